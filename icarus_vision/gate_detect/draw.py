"""Pictures of detections: true and found corners drawn on frames, and a sheet of such frames."""

from __future__ import annotations

import cv2
import numpy as np

from icarus_vision.gate_detect.base import GateDetection

TRUE_COLOUR = (0, 230, 0)
"""RGB of the true openings (green)."""
FOUND_COLOUR = (0, 255, 255)
"""RGB of the detected openings (cyan, outlined in black so they show on any gate colour); the TL
corner gets a dot."""


def draw_detections(
    image: np.ndarray, found: list[GateDetection], truth: list[np.ndarray], scale: int = 2
) -> np.ndarray:
    """The frame enlarged ``scale`` times, true openings in green, detections in cyan.

    Args:
        image: (H, W, 3) uint8 RGB.
        found: the detector's gates.
        truth: true corners (4, 2) pixels per gate (ones with a NaN corner are skipped).
        scale: enlargement (nearest neighbour), so that pixel-level errors show.

    Returns:
        (scale H, scale W, 3) uint8 RGB.
    """
    h, w = image.shape[:2]
    out = cv2.resize(image, (w * scale, h * scale), interpolation=cv2.INTER_NEAREST)

    def pts(c: np.ndarray) -> np.ndarray:  # pixel centres of the enlarged image
        return np.round((np.asarray(c) + 0.5) * scale - 0.5).astype(np.int32).reshape(-1, 1, 2)

    for c in truth:
        if np.isfinite(c).all():
            cv2.polylines(out, [pts(c)], True, TRUE_COLOUR, 1)
    for d in found:
        cv2.polylines(out, [pts(d.corners)], True, (0, 0, 0), 3)
        cv2.polylines(out, [pts(d.corners)], True, FOUND_COLOUR, 1)
        cv2.circle(out, tuple(pts(d.corners[:1]).reshape(2)), 3, FOUND_COLOUR, -1)
    return out


def sheet(tiles: list[np.ndarray], cols: int = 4) -> np.ndarray:
    """Equal-sized (h, w, 3) images in a grid, ``cols`` per row (black where the last row ends)."""
    if not tiles:
        raise ValueError("no images to put on a sheet")
    blank = np.zeros_like(tiles[0])
    tiles = tiles + [blank] * (-len(tiles) % cols)
    rows = [np.hstack(tiles[i : i + cols]) for i in range(0, len(tiles), cols)]
    return np.vstack(rows)
