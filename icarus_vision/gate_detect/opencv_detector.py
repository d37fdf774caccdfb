"""A classical gate detector, no learning: colour segmentation, contours, quadrilateral fit.

Pipeline for one RGB frame:

1. **Colour segmentation** in HSV: a pixel is "gate" when its hue falls in one of ``hue_ranges_deg``
   and its saturation and value exceed ``min_saturation`` / ``min_value``. The defaults take the
   orange and red racing gates of the default look; gates of other colours are not found (the
   baseline knows the gate colour, the CNN does not need to). A 3x3 closing fills pinholes.
2. **Contours** with a two-level hierarchy (``RETR_CCOMP``): each *hole* inside a gate-coloured
   region is a candidate opening.
3. **Quadrilateral fit** of the hole: ``approxPolyN`` to 4 vertices; kept when convex, of area
   at least ``min_area_px`` and with a side ratio and fill (contour area / quad area) that look like
   a square seen in perspective.
4. **Sub-pixel corners**: a line is fitted (``fitLine``) to the contour points of each side, away
   from the corners, and shifted half a pixel into the opening (the contour runs through the
   centres of the frame's boundary pixels); adjacent lines are intersected. ``cornerSubPix`` on the
   blurred segmentation mask then polishes each corner; a move larger than ``max_refine_px`` is
   rejected.
5. **Order** TL, TR, BR, BL: corners sorted clockwise on screen, starting from the one nearest the
   up-left diagonal from the centre (right for camera roll up to about 45 degrees).

Scores: the gate score is the hole's fill ratio times its squareness; corner scores are 1 when the
corner is inside the image and the sub-pixel refinement agreed, 0.5 otherwise.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from icarus_vision.gate_detect.base import Detector, GateDetection
from icarus_vision.gate_detect.registry import register_detector


@dataclass(frozen=True)
class OpenCvParams:
    """Parameters of :class:`OpenCvDetector`."""

    hue_ranges_deg: tuple[tuple[float, float], ...] = ((0.0, 40.0), (335.0, 360.0))
    """Gate hues, degrees in [0, 360): orange and red by default."""
    min_saturation: float = 0.45
    """Smallest HSV saturation of a gate pixel, in [0, 1]."""
    min_value: float = 0.2
    """Smallest HSV value (brightness) of a gate pixel, in [0, 1]."""
    min_area_px: float = 30.0
    """Smallest opening area, pixels^2."""
    max_side_ratio: float = 4.0
    """Largest ratio of the longest to the shortest side of the opening quadrilateral."""
    min_fill: float = 0.85
    """Smallest ratio of the hole's area to its fitted quadrilateral's area."""
    max_refine_px: float = 1.5
    """Largest correction ``cornerSubPix`` may apply to a line-intersection corner, pixels."""
    max_gates: int = 20
    """Most gates reported per image."""


def gate_mask(image: np.ndarray, p: OpenCvParams) -> np.ndarray:
    """(H, W) uint8 mask (255 = gate colour) of an (H, W, 3) uint8 RGB image."""
    hsv = cv2.cvtColor(image, cv2.COLOR_RGB2HSV_FULL)  # hue scaled to 0-255
    h, s, v = hsv[..., 0], hsv[..., 1], hsv[..., 2]
    hue_ok = np.zeros(h.shape, bool)
    for lo, hi in p.hue_ranges_deg:
        lo8, hi8 = lo / 360.0 * 256.0, hi / 360.0 * 256.0
        hue_ok |= (h >= lo8) & (h <= hi8)
    mask = hue_ok & (s >= p.min_saturation * 255) & (v >= p.min_value * 255)
    mask = mask.astype(np.uint8) * 255
    return cv2.morphologyEx(mask, cv2.MORPH_CLOSE, np.ones((3, 3), np.uint8))


def order_corners(quad: np.ndarray) -> np.ndarray:
    """(4, 2) corners in any order -> TL, TR, BR, BL (clockwise on screen from the up-left one)."""
    c = quad.mean(axis=0)
    ang = np.arctan2(quad[:, 1] - c[1], quad[:, 0] - c[0])  # v points down: clockwise increases
    quad = quad[np.argsort(ang)]
    ang = np.sort(ang)
    diff = np.angle(np.exp(1j * (ang + 0.75 * np.pi)))
    return np.roll(quad, -int(np.argmin(np.abs(diff))), axis=0)


def _side_lines(contour: np.ndarray, quad_idx: np.ndarray, centre: np.ndarray) -> list | None:
    """A line (point, direction) per side, fitted to the contour points between two vertices."""
    n = len(contour)
    lines = []
    for k in range(4):
        a, b = int(quad_idx[k]), int(quad_idx[(k + 1) % 4])
        idx = np.arange(a, b + 1 if b >= a else b + n + 1) % n
        m = len(idx)
        trim = int(0.15 * m)
        pts = contour[idx[trim : m - trim] if m - 2 * trim >= 2 else idx].astype(np.float32)
        if len(pts) < 2:
            return None
        vx, vy, x0, y0 = cv2.fitLine(pts, cv2.DIST_HUBER, 0, 0.01, 0.01).ravel()
        d = np.array([vx, vy], float)
        q = np.array([x0, y0], float)
        normal = np.array([-d[1], d[0]])
        if np.dot(centre - q, normal) < 0:
            normal = -normal
        lines.append((q + 0.5 * normal, d))  # half a pixel into the opening
    return lines


def _intersect(l1, l2) -> np.ndarray | None:
    (p1, d1), (p2, d2) = l1, l2
    a = np.array([d1, -d2]).T
    if abs(np.linalg.det(a)) < 1e-6:
        return None
    t = np.linalg.solve(a, p2 - p1)
    return p1 + t[0] * d1


class OpenCvDetector(Detector):
    """The classical baseline (see the module docstring).

    Args:
        params: segmentation and fitting parameters.
    """

    name = "opencv"

    def __init__(self, params: OpenCvParams = OpenCvParams()) -> None:
        self.params = params

    def _detect(self, image: np.ndarray) -> list[GateDetection]:
        p = self.params
        mask = gate_mask(image, p)
        contours, hier = cv2.findContours(mask, cv2.RETR_CCOMP, cv2.CHAIN_APPROX_NONE)
        if hier is None:
            return []
        soft = cv2.GaussianBlur(mask.astype(np.float32), (5, 5), 1.0)
        h, w = mask.shape
        found = []
        for i, cnt in enumerate(contours):
            if hier[0, i, 3] < 0:  # an outer boundary, not a hole
                continue
            det = self._fit(cnt.reshape(-1, 2), soft, (w, h))
            if det is not None:
                found.append(det)
        found.sort(key=lambda d: -d.score)
        return found[: p.max_gates]

    def _fit(self, cnt: np.ndarray, soft: np.ndarray, size: tuple[int, int]):
        p = self.params
        area = cv2.contourArea(cnt.astype(np.float32))
        if area < p.min_area_px or len(cnt) < 8:
            return None
        quad = cv2.approxPolyN(cnt.reshape(-1, 1, 2), 4, ensure_convex=True).reshape(-1, 2)
        if len(quad) != 4:
            return None
        quad_area = cv2.contourArea(quad.astype(np.float32))
        sides = np.linalg.norm(quad - np.roll(quad, -1, axis=0), axis=1)
        if quad_area <= 0 or sides.min() <= 0 or sides.max() / sides.min() > p.max_side_ratio:
            return None
        fill = min(area / quad_area, quad_area / area)
        if fill < p.min_fill:
            return None
        # Indices of the contour points nearest each vertex, in contour order.
        d = np.linalg.norm(cnt[None, :, :] - quad[:, None, :], axis=2)
        idx = np.argmin(d, axis=1)
        order = np.argsort(idx)
        idx, quad = idx[order], quad[order]
        centre = cnt.mean(axis=0)
        lines = _side_lines(cnt, idx, centre)
        if lines is None:
            return None
        corners = [_intersect(lines[k - 1], lines[k]) for k in range(4)]
        if any(c is None for c in corners):
            return None
        corners = np.array(corners)
        if np.linalg.norm(corners - quad, axis=1).max() > max(3.0, 0.2 * sides.min()):
            return None  # the sides are not straight: not a square opening
        corners, refined = self._refine(corners, soft, sides.min())
        corners = order_corners(corners)
        w, h = size
        inside = (corners[:, 0] >= 0) & (corners[:, 0] <= w - 1)
        inside &= (corners[:, 1] >= 0) & (corners[:, 1] <= h - 1)
        scores = np.where(inside & refined, 1.0, 0.5)
        squareness = sides.min() / sides.max()
        return GateDetection(corners, scores, float(np.clip(fill * squareness**0.5, 0, 1)))

    def _refine(self, corners: np.ndarray, soft: np.ndarray, side: float):
        """``cornerSubPix`` on the blurred mask; keep the line corner where it moves too far."""
        win = int(np.clip(side / 6.0, 2, 5))
        pts = corners.astype(np.float32).reshape(-1, 1, 2).copy()
        h, w = soft.shape
        ok = (pts[:, 0, 0] > win + 1) & (pts[:, 0, 0] < w - win - 2)
        ok &= (pts[:, 0, 1] > win + 1) & (pts[:, 0, 1] < h - win - 2)
        if not ok.any():
            return corners, np.zeros(4, bool)
        crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 20, 0.01)
        sub = pts[ok].copy()
        cv2.cornerSubPix(soft, sub, (win, win), (-1, -1), crit)
        out, refined = corners.copy(), np.zeros(4, bool)
        moved = np.linalg.norm(sub[:, 0] - pts[ok, 0], axis=1)
        for j, k in enumerate(np.flatnonzero(ok)):
            if moved[j] <= self.params.max_refine_px:
                out[k], refined[k] = sub[j, 0], True
        return out, refined


register_detector("opencv", lambda arg: OpenCvDetector())
