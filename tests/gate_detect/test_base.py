"""The detector interface: input validation, detection records, and the oracle detector."""

from __future__ import annotations

import numpy as np
import pytest

from icarus_vision.gate_detect import (
    GateDetection,
    OracleDetector,
    available_detectors,
    make_detector,
    validate_image,
)
from icarus_vision.render.camera import Camera
from icarus_vision.sim.track import Gate, Track

LEVEL = np.array([0.0, 0.0, 0.0, 1.0])
TRACK = Track("one", (Gate((4.0, 0.0, 2.0)),), start_pos=(0.0, 0.0, 0.2))
CAM = Camera(uptilt_deg=0.0)


def _detectors():
    """Every detector the contract runs on: the oracle plus every registered image detector."""
    oracle = OracleDetector(TRACK, CAM)
    oracle.set_pose(np.array([0.0, 0.0, 2.0]), LEVEL)
    return [oracle, *(make_detector(name) for name in available_detectors())]


@pytest.mark.parametrize("det", _detectors(), ids=lambda d: d.name)
@pytest.mark.parametrize(
    "image",
    [
        np.zeros((240, 320, 3), np.float32),
        np.zeros((240, 320), np.uint8),
        np.zeros((240, 320, 4), np.uint8),
        np.zeros((0, 320, 3), np.uint8),
        [[0, 0, 0]],
    ],
    ids=["float", "gray", "rgba", "empty", "list"],
)
def test_bad_images_are_refused(det, image):
    with pytest.raises(ValueError, match="uint8|shape|array|empty"):
        det.detect(image)


@pytest.mark.parametrize("det", _detectors(), ids=lambda d: d.name)
def test_output_contract(det):
    out = det.detect(np.zeros((240, 320, 3), np.uint8))
    assert isinstance(out, list)
    for d in out:
        assert isinstance(d, GateDetection)
        assert d.corners.shape == (4, 2) and d.corner_scores.shape == (4,)
        assert 0.0 <= d.score <= 1.0


def test_validate_image_passes_good_input():
    img = np.zeros((8, 8, 3), np.uint8)
    assert validate_image(img) is img


def test_detection_shapes_are_checked():
    with pytest.raises(ValueError, match="corners"):
        GateDetection(np.zeros((3, 2)), np.ones(4), 1.0)
    with pytest.raises(ValueError, match="corner_scores"):
        GateDetection(np.zeros((4, 2)), np.ones(3), 1.0)


def test_oracle_projects_true_corners():
    det = OracleDetector(TRACK, CAM)
    out = det.detect_pose(np.array([0.0, 0.0, 2.0]), LEVEL)
    assert len(out) == 1
    px, _ = CAM.project(TRACK.gates[0].corners(), np.array([0.0, 0.0, 2.0]), LEVEL)
    np.testing.assert_allclose(out[0].corners, px)
    # Looking straight at it: TL is up-left of BR on screen.
    assert (
        out[0].corners[0, 0] < out[0].corners[2, 0] and out[0].corners[0, 1] < out[0].corners[2, 1]
    )


def test_oracle_sees_nothing_behind_or_from_behind():
    det = OracleDetector(TRACK, CAM)
    behind = np.array([0.0, 0.0, 1.0, 0.0])  # yawed 180 degrees
    assert det.detect_pose(np.array([0.0, 0.0, 2.0]), behind) == []
    # From the exit side the gate's (only) passage is not faced: nothing reported.
    assert det.detect_pose(np.array([8.0, 0.0, 2.0]), behind) == []


def test_oracle_noise_and_misses_are_seeded():
    pos = np.array([0.0, 0.0, 2.0])
    a = OracleDetector(TRACK, CAM, sigma_px=1.0, seed=3).detect_pose(pos, LEVEL)
    b = OracleDetector(TRACK, CAM, sigma_px=1.0, seed=3).detect_pose(pos, LEVEL)
    np.testing.assert_array_equal(a[0].corners, b[0].corners)
    clean = OracleDetector(TRACK, CAM).detect_pose(pos, LEVEL)[0].corners
    assert 0.0 < np.abs(a[0].corners - clean).max() < 6.0
    assert OracleDetector(TRACK, CAM, miss_rate=1.0).detect_pose(pos, LEVEL) == []
    with pytest.raises(ValueError):
        OracleDetector(TRACK, CAM, miss_rate=1.5)


def test_oracle_reads_visibility_from_a_rendered_frame():
    from icarus_vision.render.scene import Scene

    scene = Scene(TRACK, CAM)
    try:
        pos = np.array([0.0, 0.0, 2.0])
        frame = scene.render(pos, LEVEL)
        det = OracleDetector(TRACK, CAM, gate_bodies=scene.gate_bodies)
        det.set_pose(pos, LEVEL, frame)
        out = det.detect(frame.rgb)
        assert len(out) == 1
        np.testing.assert_allclose(out[0].corners, det.detect_pose(pos, LEVEL)[0].corners)
    finally:
        scene.close()


def test_unknown_image_detector_lists_the_known_ones():
    with pytest.raises(ValueError, match="unknown detector .nosuch.; choose one of .*cnn.*opencv"):
        make_detector("nosuch")


def test_settings_reach_the_detector_that_takes_them():
    assert make_detector("cnn", backend="torch").backend == "torch"
    with pytest.raises(ValueError, match="the opencv detector takes no setting backend"):
        make_detector("opencv", backend="int8")
    with pytest.raises(ValueError, match="the cnn detector takes no setting colour"):
        make_detector("cnn", colour="red")
