"""Simulated odometry: exact without noise, drifting with it, seeded."""

from __future__ import annotations

import numpy as np
import pytest

from icarus_vision.estimator import OdometryConfig, SimulatedOdometry

Q = np.array([0.0, 0.0, 0.3826834, 0.9238795])


def _run(odo, n=500, dt=0.02):
    return [
        odo.measure(k * dt, [1.0, 2.0, 3.0], [1.0, 0.0, 0.0], Q, [0.0, 0.0, 0.1]) for k in range(n)
    ]


def test_zero_noise_is_exact():
    zero = OdometryConfig(0, 0, 0, 0, 0, 0)
    r = _run(SimulatedOdometry(zero), n=3)[-1]
    np.testing.assert_allclose(r.pos, [1.0, 2.0, 3.0])
    np.testing.assert_allclose(r.quat, Q, atol=1e-7)


def test_drift_grows_and_is_seeded():
    a = _run(SimulatedOdometry(OdometryConfig(), seed=5))
    b = _run(SimulatedOdometry(OdometryConfig(), seed=5))
    np.testing.assert_array_equal(a[-1].pos, b[-1].pos)
    err = np.array([np.linalg.norm(r.pos - [1.0, 2.0, 3.0]) for r in a])
    assert err[-50:].mean() > err[:50].mean()  # 10 s of drift vs white noise
    assert err.max() < 0.5


def test_bad_input_and_config():
    with pytest.raises(ValueError, match="not finite"):
        SimulatedOdometry().measure(0.0, [np.nan, 0, 0], [0, 0, 0], Q, [0, 0, 0])
    with pytest.raises(ValueError):
        OdometryConfig(pos_noise_m=-1.0)
