"""The classical detector: a clean rendered gate within 1 px, corner ordering, segmentation."""

from __future__ import annotations

import numpy as np
import pytest

from icarus_vision.gate_detect.opencv_detector import (
    OpenCvDetector,
    OpenCvParams,
    gate_mask,
    order_corners,
)
from icarus_vision.render.camera import Camera
from icarus_vision.render.scene import Scene
from icarus_vision.sim.track import Gate, Track

TRACK = Track("one", (Gate((4.0, 0.0, 2.0)),), start_pos=(0.0, 0.0, 0.2))
CAM = Camera(uptilt_deg=0.0)


@pytest.fixture(scope="module")
def scene():
    with Scene(TRACK, CAM) as s:  # the default look: an orange gate
        yield s


def _yaw(deg: float) -> np.ndarray:
    a = np.radians(deg) / 2
    return np.array([0.0, 0.0, np.sin(a), np.cos(a)])


@pytest.mark.parametrize(
    "pos, yaw_deg, tol",
    [((0.0, 0.0, 2.0), 0.0, 1.0), ((-2.0, 0.0, 2.0), 0.0, 1.0), ((0.5, 0.6, 2.3), 6.0, 1.5)],
    ids=["ahead-4m", "ahead-6m", "offset-yawed"],
)
def test_finds_rendered_gate_corners(scene, pos, yaw_deg, tol):
    pos, quat = np.array(pos), _yaw(yaw_deg)
    frame = scene.render(pos, quat)
    truth, _ = CAM.project(TRACK.gates[0].corners(), pos, quat)
    found = OpenCvDetector().detect(frame.rgb)
    assert len(found) == 1
    err = np.linalg.norm(found[0].corners - truth, axis=1)
    assert err.max() < tol, err


@pytest.mark.parametrize("roll_deg", [-40.0, -10.0, 0.0, 10.0, 40.0])
def test_order_corners_tl_tr_br_bl(roll_deg):
    square = np.array([[-1.0, -1.0], [1.0, -1.0], [1.0, 1.0], [-1.0, 1.0]])  # TL TR BR BL, v down
    a = np.radians(roll_deg)
    rot = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
    quad = square @ rot.T * 30 + [160, 120]
    shuffled = quad[[2, 0, 3, 1]]
    np.testing.assert_allclose(order_corners(shuffled), quad)


def test_mask_takes_only_the_configured_hues():
    img = np.zeros((10, 30, 3), np.uint8)
    img[:, :10] = (255, 90, 0)  # orange
    img[:, 10:20] = (30, 80, 230)  # blue
    img[:, 20:] = (128, 128, 128)  # grey
    m = gate_mask(img, OpenCvParams())
    assert m[:, 2:8].all() and not m[:, 12:18].any() and not m[:, 22:28].any()
    blue = gate_mask(img, OpenCvParams(hue_ranges_deg=((200.0, 240.0),)))
    assert blue[:, 12:18].all() and not blue[:, 2:8].any()
