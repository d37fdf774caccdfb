"""Pictures of detections."""

from __future__ import annotations

import numpy as np
import pytest

from icarus_vision.gate_detect.base import GateDetection
from icarus_vision.gate_detect.draw import FOUND_COLOUR, TRUE_COLOUR, draw_detections, sheet

SQUARE = np.array([[10.0, 10.0], [30.0, 10.0], [30.0, 30.0], [10.0, 30.0]])


def test_truth_and_detections_are_drawn_at_their_corners_enlarged():
    img = np.zeros((40, 50, 3), np.uint8)
    found = [GateDetection(SQUARE + 5.0, np.ones(4), 0.9)]
    out = draw_detections(img, found, [SQUARE, np.full((4, 2), np.nan)], scale=2)
    assert out.shape == (80, 100, 3)
    # pixel u maps into its 2x2 block: (u + 0.5) * 2 - 0.5, rounded (half to even)
    assert (out[25:55, 20] == TRUE_COLOUR).all()  # the true left edge, u = 10
    assert (out[35:65, 30] == FOUND_COLOUR).all()  # the detection's, u = 15
    assert (out[0, :] == 0).all()  # nothing drawn for the gate with a NaN corner


def test_sheet_fills_the_last_row():
    tiles = [np.full((2, 3, 3), i, np.uint8) for i in range(5)]
    out = sheet(tiles, cols=4)
    assert out.shape == (4, 12, 3) and out[2:, 3:].max() == 0 and out[2, 0, 0] == 4
    with pytest.raises(ValueError):
        sheet([])
