"""Compiled homographies: OpenCV's, bit for bit, for a whole frame's quadrilaterals at once."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from icarus_vision.gate_detect.cnn.homography import perspective, transform

SQUARE = np.array([[11.5, 11.5], [35.5, 11.5], [35.5, 35.5], [11.5, 35.5]])


def _quads(n: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return rng.uniform(0, 300, (n, 1, 2)) + rng.normal(0, 20, (n, 4, 2))


def test_perspective_is_opencvs_bit_for_bit_both_ways():
    quads = _quads(500)
    ours, back = perspective(quads, SQUARE), perspective(SQUARE, quads)
    for q, h, b in zip(quads.astype(np.float32), ours, back, strict=True):
        np.testing.assert_array_equal(h, cv2.getPerspectiveTransform(q, SQUARE.astype(np.float32)))
        np.testing.assert_array_equal(b, cv2.getPerspectiveTransform(SQUARE.astype(np.float32), q))


def test_a_homography_and_its_reverse_undo_each_other():
    quads = _quads(50, seed=1)
    there = transform(perspective(quads, SQUARE), quads)
    np.testing.assert_allclose(
        there, np.broadcast_to(SQUARE, quads.shape), atol=0.01
    )  # the points as float32
    np.testing.assert_allclose(
        transform(perspective(SQUARE, quads), there), quads, atol=0.01
    )  # the points as float32


def test_collinear_corners_give_a_null_homography():
    line = np.array([[0.0, 0.0], [1.0, 1.0], [2.0, 2.0], [3.0, 3.0]])
    np.testing.assert_array_equal(perspective(line, SQUARE)[0], np.diag([0.0, 0.0, 1.0]))


def test_mismatched_counts_are_refused():
    with pytest.raises(ValueError, match="3 source and 2 destination"):
        perspective(_quads(3), _quads(2))
    with pytest.raises(ValueError, match=r"expected \(N, 3, 3\) and \(N, K, 2\)"):
        transform(np.eye(3)[None], np.zeros((2, 4, 2)))
    assert perspective(np.zeros((0, 4, 2)), SQUARE).shape == (0, 3, 3)
