"""The phased INTER_AREA resize gives OpenCV's output byte for byte, and falls back elsewhere; frames
of other aspect ratios are letterboxed, not stretched."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from icarus_vision.gate_detect.cnn.data import read_rgb
from icarus_vision.gate_detect.cnn.model import PAD_VALUE, letterbox_size, network_input
from icarus_vision.gate_detect.cnn.resize import EXACT_RATIOS, area_resize, area_taps


def test_taps_are_inter_area_weights_at_5_to_4():
    p, q, phases = area_taps(320, 256)
    assert (p, q) == (5, 4)
    assert [k for k, _, _ in phases] == [0, 1, 2, 3]
    np.testing.assert_allclose([(a, b) for _, a, b in phases],
                               [(0.8, 0.2), (0.6, 0.4), (0.4, 0.6), (0.2, 0.8)])  # fmt: skip
    for n_in, n_out in [(320, 320), (320, 160), (320, 100), (320, 400)]:
        assert area_taps(n_in, n_out) is None  # not shrinking, or by 2 or more


@pytest.mark.parametrize("ratio", sorted(EXACT_RATIOS))
def test_exact_ratios_match_opencv_on_random_images(ratio):
    p, q = ratio
    rng = np.random.default_rng(0)
    w, h = 24 * p, 18 * p
    for _ in range(20):
        image = rng.integers(0, 256, (h, w, 3), dtype=np.uint8)
        expected = cv2.resize(image, (w * q // p, h * q // p), interpolation=cv2.INTER_AREA)
        np.testing.assert_array_equal(area_resize(image, (w * q // p, h * q // p)), expected)


@pytest.mark.parametrize(
    ("shape", "size"),
    [
        ((240, 320, 3), (256, 180)),  # 5:4 and 4:3: not exact together, falls back
        ((240, 320, 3), (224, 168)),  # 10:7: an output pixel spans three
        ((240, 321, 3), (256, 192)),  # not whole periods
        ((240, 320, 3), (160, 120)),
    ],  # fmt: skip
)
def test_other_shapes_fall_back_to_opencv(shape, size):
    image = np.random.default_rng(1).integers(0, 256, shape, dtype=np.uint8)
    expected = cv2.resize(image, size, interpolation=cv2.INTER_AREA)
    np.testing.assert_array_equal(area_resize(image, size), expected)


def test_network_input_of_rendered_frames_is_inter_area(tiny_dataset):
    files = sorted((tiny_dataset / "images").rglob("*.png"))[:6]
    assert files
    for f in files:
        frame = read_rgb(f)  # 160x120: to 128x96 is 5:4, as 320x240 to the shipped 256x192
        expected = cv2.resize(frame, (128, 96), interpolation=cv2.INTER_AREA)
        np.testing.assert_array_equal(network_input(frame, (128, 96)), expected)


@pytest.mark.parametrize("size", [(640, 240), (315, 160), (360, 360), (240, 320)])
def test_frames_of_other_aspects_are_letterboxed_not_stretched(size):
    """A square stays square in what the network reads, at the frame's top-left; the rest is
    the padding's grey."""
    w, h = size
    side = min(w, h) // 2
    frame = np.zeros((h, w, 3), np.uint8)
    frame[:side, :side] = 255
    x = network_input(frame, (256, 192))
    pw, ph = letterbox_size(size, (256, 192))
    assert pw * 192 == pytest.approx(ph * 256, abs=256) and (pw, ph) >= (w, h)
    white = np.argwhere(x[..., 0] > 128)
    rows, cols = np.ptp(white[:, 0]) + 1, np.ptp(white[:, 1]) + 1
    assert abs(rows - cols) <= 1 and white.min(axis=0).tolist() == [0, 0]
    assert x[-1, -1, 0] == (PAD_VALUE if (pw, ph) != (w, h) else 0)


def test_the_detector_reads_a_wide_frame_in_its_own_pixels():
    """The shipped CNN on a 4:3 frame and on the same frame widened to 2:1 with grey: the same
    gate, in the same pixels."""
    from icarus_vision.gate_detect.registry import make_detector
    from tests.gate_detect.conftest import QUAD, gate_image

    det = make_detector("cnn")
    frame = gate_image()
    wide = np.ascontiguousarray(np.concatenate([frame, np.full_like(frame, 110)], axis=1))
    (a,), (b,) = det.detect(frame), det.detect(wide)
    assert np.abs(a.corners - QUAD).max() < 4.0
    assert np.abs(a.corners - b.corners).max() < 1.5
