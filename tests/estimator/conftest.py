"""Helpers: a straight approach to gates with exact odometry and the oracle as detector."""

from __future__ import annotations

import numpy as np
import pytest

from icarus_vision.estimator import OdometryReading
from icarus_vision.render.camera import Camera
from icarus_vision.sim.dynamics import rpy_to_quat
from icarus_vision.sim.track import Gate, Track

CAM = Camera()  # the default 320x240, 90 degrees, 20 degrees uptilt


def odom_at(t: float, pos, yaw: float = 0.0, pitch: float = 0.0) -> OdometryReading:
    """An exact odometry reading of a drone at ``pos`` with heading ``yaw`` (rad)."""
    q = rpy_to_quat(np.array([[0.0, pitch, yaw]]))[0]
    return OdometryReading(float(t), np.asarray(pos, float), np.zeros(3), q, np.zeros(3))


@pytest.fixture
def two_gates() -> Track:
    """Two gates in a row along +x at 2 m height (passed along +x)."""
    return Track("two", (Gate((6.0, 0.0, 2.0)), Gate((14.0, 1.0, 2.0), yaw_deg=10.0)))
