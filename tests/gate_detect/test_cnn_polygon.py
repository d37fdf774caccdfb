"""Quadrilateral overlap (compiled), against OpenCV's convex-polygon routines."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from icarus_vision.gate_detect.cnn.polygon import quad_iou

SQUARE = np.array([[0.0, 0.0], [2.0, 0.0], [2.0, 2.0], [0.0, 2.0]])


def _opencv_iou(a: np.ndarray, b: np.ndarray) -> float:
    ha, hb = cv2.convexHull(a.astype(np.float32)), cv2.convexHull(b.astype(np.float32))
    inter, _ = cv2.intersectConvexConvex(ha, hb)
    union = cv2.contourArea(ha) + cv2.contourArea(hb) - inter
    return min(float(inter / union), 1.0) if union > 0 else 0.0


def test_quad_iou_of_shifted_squares():
    assert quad_iou(SQUARE, SQUARE) == pytest.approx(1.0)
    assert quad_iou(SQUARE, SQUARE + (1.0, 0.0)) == pytest.approx(2.0 / 6.0)
    assert quad_iou(SQUARE, SQUARE[[2, 3, 0, 1]] + (1.0, 1.0)) == pytest.approx(1.0 / 7.0)
    assert quad_iou(SQUARE, SQUARE + (5.0, 0.0)) == 0.0
    assert quad_iou(SQUARE, SQUARE + (2.0, 0.0)) == 0.0  # sharing an edge only


def test_quad_iou_matches_opencv_on_random_quadrilaterals():
    rng = np.random.default_rng(0)
    for i in range(600):
        a = rng.uniform(0, 50, 2) + rng.normal(0, 10, (4, 2))  # often not convex
        b = (
            a + rng.normal(0, 3, (4, 2))
            if i % 2
            else rng.uniform(0, 50, 2) + rng.normal(0, 10, (4, 2))
        )
        assert quad_iou(a, b) == pytest.approx(_opencv_iou(a, b), abs=1e-5)
        assert quad_iou(a, b) == pytest.approx(quad_iou(b, a), abs=1e-12)


def test_degenerate_quadrilaterals_overlap_nothing():
    line = np.array([[0.0, 0.0], [1.0, 1.0], [2.0, 2.0], [3.0, 3.0]])
    assert quad_iou(line, SQUARE) == 0.0
    assert quad_iou(np.zeros((4, 2)), np.zeros((4, 2))) == 0.0
