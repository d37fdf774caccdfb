"""The phased INTER_AREA resize gives OpenCV's output byte for byte, and falls back elsewhere."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from icarus_vision.gate_detect.cnn.data import read_rgb
from icarus_vision.gate_detect.cnn.model import network_input
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
