"""Rectifying a candidate gate: the homography that maps its corners onto a square in a small
patch, the patch itself, and corners between the patch and the camera image.

The refiner (``refine.py``) reads these patches. Everything here is pure geometry on (N, ...)
arrays of a frame's candidates, camera pixels (u, v) and corner order TL, TR, BR, BL throughout.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import cv2
import numpy as np
import torch
from numba import njit

from icarus_vision.gate_detect.base import FLIP_ORDER
from icarus_vision.gate_detect.cnn.homography import apply, perspective, transform
from icarus_vision.gate_detect.cnn.model import to_float
from icarus_vision.gate_detect.cnn.polygon import mean_side

if TYPE_CHECKING:
    from icarus_vision.gate_detect.cnn.refine import RefineConfig


def square(cfg: RefineConfig) -> np.ndarray:
    """(4, 2) where a candidate's corners TL, TR, BR, BL land in the patch (pixel centres)."""
    lo, hi = cfg.margin - 0.5, cfg.patch - cfg.margin - 0.5
    return np.array([[lo, lo], [hi, lo], [hi, hi], [lo, hi]], np.float64)


def homographies(quads: np.ndarray, cfg: RefineConfig) -> np.ndarray:
    """(N, 3, 3) homographies from camera pixels to the patch, one per (4, 2) candidate.

    Args:
        quads: (N, 4, 2) candidate corners, camera pixels, TL, TR, BR, BL.
    """
    return perspective(quads, square(cfg))


def patch_to_image(quads: np.ndarray, cfg: RefineConfig) -> np.ndarray:
    """(N, 3, 3) inverses of :func:`homographies`: from the patch back to camera pixels
    (computed as such: cheaper than inverting them)."""
    return perspective(square(cfg), quads)


def extract(image: np.ndarray, h: np.ndarray, cfg: RefineConfig) -> np.ndarray:
    """(N, P, P, 3) uint8 patches of ``image`` (H, W, 3) under (N, 3, 3) homographies (black
    outside the image)."""
    out = np.empty((len(h), cfg.patch, cfg.patch, 3), np.uint8)
    for i, m in enumerate(h):
        out[i] = cv2.warpPerspective(
            image, m, (cfg.patch, cfg.patch), flags=cv2.INTER_LINEAR,
            borderMode=cv2.BORDER_CONSTANT, borderValue=0,
        )  # fmt: skip
    return out


def usable(quads: np.ndarray, min_side_px: float = 4.0) -> np.ndarray:
    """(N,) bool: candidates whose quadrilateral is finite, convex, correctly ordered (clockwise
    in the image, y down) and not tiny (mean side at least ``min_side_px``), so that their
    homography is well defined."""
    return _usable(np.ascontiguousarray(quads, np.float64).reshape(-1, 4, 2), float(min_side_px))


@njit(cache=True)
def _usable(q: np.ndarray, min_side_px: float) -> np.ndarray:
    ok = np.empty(len(q), np.bool_)
    for n in range(len(q)):
        good, sides = np.isfinite(q[n]).all(), 0.0
        for i in range(4):
            j, k = (i + 1) % 4, (i + 2) % 4
            ex, ey = q[n, j, 0] - q[n, i, 0], q[n, j, 1] - q[n, i, 1]
            fx, fy = q[n, k, 0] - q[n, j, 0], q[n, k, 1] - q[n, j, 1]
            good &= ex * fy - ey * fx > 0.0
            sides += np.sqrt(ex * ex + ey * ey)
        ok[n] = good and sides / 4 >= min_side_px
    return ok


def settle(quads: np.ndarray, corners: np.ndarray, side: float) -> tuple[np.ndarray, np.ndarray]:
    """Where a reading leaves (N, 4, 2) candidates: its corrected ``corners``, or the candidate
    as it was where they are not :func:`usable` (a reading that folded it); and (N,) how far
    that moved each, the largest change of a corner's x or y in patch pixels (camera pixels times
    ``side`` over the candidate's mean side)."""
    return _settle(
        np.ascontiguousarray(quads, np.float64).reshape(-1, 4, 2),
        np.ascontiguousarray(corners, np.float64).reshape(-1, 4, 2),
        float(side),
    )


@njit(cache=True, error_model="numpy")
def _settle(quads: np.ndarray, corners: np.ndarray, side: float) -> tuple[np.ndarray, np.ndarray]:
    ok = _usable(corners, 4.0)
    out, shift = quads.copy(), np.zeros(len(quads))
    for n in range(len(quads)):
        if ok[n]:
            out[n] = corners[n]
            shift[n] = np.abs(corners[n] - quads[n]).max() * side / mean_side(quads[n])
    return out, shift


def offsets_to_corners(
    h: np.ndarray,
    offsets: np.ndarray,
    cfg: RefineConfig,
    mirrored: np.ndarray | None = None,
    back: np.ndarray | None = None,
) -> np.ndarray:
    """Corrected corners in camera pixels: (N, 8) network offsets under (N, 3, 3) homographies
    -> (N, 4, 2).

    Args:
        mirrored: also (N, 8) offsets read from each patch mirrored left to right (corner order
            swapped: :func:`mirrored`); then the mean of both readings' corners, in the image.
        back: the homographies' inverses (patch to camera: :func:`patch_to_image`), if known;
            ``h`` is then not used.
    """
    back = np.linalg.inv(h) if back is None else back
    offsets = np.ascontiguousarray(offsets, np.float64).reshape(-1, 4, 2)
    flip = None if mirrored is None else np.ascontiguousarray(mirrored, np.float64)
    lo = cfg.margin - 0.5
    return _offsets_to_corners(
        np.ascontiguousarray(back, np.float64), offsets,
        None if flip is None else flip.reshape(-1, 4, 2), lo, float(cfg.side), cfg.patch - 1.0,
    )  # fmt: skip


_FLIP = tuple(FLIP_ORDER)


@njit(cache=True, error_model="numpy")
def _offsets_to_corners(back, offsets, mirrored, lo, side, width):
    """:func:`offsets_to_corners`: the square's corners (``lo`` and ``lo + side``) plus the
    offsets times ``side``, to the image; with ``mirrored`` offsets, their corners too (x to
    ``width - x``, order flipped) and the mean of both in the image."""
    out = np.empty_like(offsets)
    for n in range(len(offsets)):
        m = back[n]
        for c in range(4):
            x = lo + side * (c == 1 or c == 2) + offsets[n, c, 0] * side
            y = lo + side * (c >= 2) + offsets[n, c, 1] * side
            u, v = apply(m, x, y)
            if mirrored is not None:
                f = _FLIP[c]  # the mirrored reading's corner that is this one
                x = width - (lo + side * (f == 1 or f == 2) + mirrored[n, f, 0] * side)
                y = lo + side * (f >= 2) + mirrored[n, f, 1] * side
                u2, v2 = apply(m, x, y)
                u, v = 0.5 * (u + u2), 0.5 * (v + v2)
            out[n, c, 0], out[n, c, 1] = u, v
    return out


def corners_to_offsets(h: np.ndarray, corners: np.ndarray, cfg: RefineConfig) -> np.ndarray:
    """The network's targets: (N, 4, 2) true corners, camera pixels -> (N, 8) offsets."""
    return ((transform(h, corners) - square(cfg)[None]) / cfg.side).reshape(-1, 8)


def to_tensor(patches: np.ndarray) -> torch.Tensor:
    """(N, P, P, 3) uint8 -> (N, 3, P, P) float32 in [0, 1] (channels-last memory: no copy)."""
    return torch.from_numpy(patches).permute(0, 3, 1, 2).float().div_(255.0)


def network_patches(patches: np.ndarray, mirror: bool = False) -> np.ndarray:
    """(N, P, P, 3) uint8 -> (N, 3, P, P) float32 in [0, 1], contiguous (what ONNX Runtime
    reads, in one pass); with ``mirror``, (2N, ...): the patches, then each mirrored left to
    right. The values are :func:`to_tensor`'s."""
    n, p = len(patches), patches.shape[1]
    out = np.empty((2 * n if mirror else n, 3, p, p), np.float32)
    to_float(patches, out[:n])
    if mirror:
        out[n:] = out[:n, :, :, ::-1]
    return out


def mirrored(quads: np.ndarray, width: int) -> tuple[np.ndarray, np.ndarray]:
    """The mirrored reading of (N, 4, 2) candidates in a frame ``width`` pixels wide: the corners
    to rectify (the corner order swapped, so the patch comes out mirrored) and where the
    candidate lies in the mirror image (what ``refine.geometry`` is told)."""
    flipped = quads[:, FLIP_ORDER]
    where = flipped.copy()
    where[..., 0] = width - 1 - where[..., 0]
    return flipped, where


def squareness(quads: np.ndarray, image_size: tuple[int, int], hfov_deg: float) -> np.ndarray:
    """(N, 2) how far each (4, 2) quadrilateral is from the image of a square: log of the ratio
    of its two sides' lengths in 3-D, and the cosine of the angle between them (both 0 for a
    square), under a pinhole camera of ``hfov_deg`` with a centred principal point.

    The homography H from the unit square to the quadrilateral is K [r1 r2 t] up to scale, r1
    and r2 the square's two edge directions scaled by its size; a square has |r1| = |r2| and
    r1 . r2 = 0. Gate-like frames that are not square (the dataset's distractors) fail this in
    most views, though rectifying the candidate hides its shape from the patch. A camera whose
    field of view differs from ``hfov_deg`` shifts both values a little (a refiner learns that
    spread, as the training data's fields of view vary).
    """
    w, h = image_size
    f = 0.5 * w / math.tan(math.radians(hfov_deg) / 2.0)
    return _squareness(perspective(_UNIT_SQUARE, quads), f, (w - 1) / 2.0, (h - 1) / 2.0)


@njit(cache=True, error_model="numpy")
def _squareness(homographies: np.ndarray, f: float, cx: float, cy: float) -> np.ndarray:
    out = np.zeros((len(homographies), 2))
    r = np.empty((3, 2))
    for n in range(len(homographies)):
        m = homographies[n]
        for j in range(2):  # K^-1 H's first two columns: r1, r2 (up to scale)
            r[0, j] = (m[0, j] - cx * m[2, j]) / f
            r[1, j] = (m[1, j] - cy * m[2, j]) / f
            r[2, j] = m[2, j]
        g00 = r[0, 0] ** 2 + r[1, 0] ** 2 + r[2, 0] ** 2
        g11 = r[0, 1] ** 2 + r[1, 1] ** 2 + r[2, 1] ** 2
        g01 = r[0, 0] * r[0, 1] + r[1, 0] * r[1, 1] + r[2, 0] * r[2, 1]
        aspect = min(max(0.5 * np.log(g00 / g11), -3.0), 3.0)
        cos = min(max(g01 / np.sqrt(g00 * g11), -1.0), 1.0)
        out[n, 0] = 0.0 if np.isnan(aspect) else aspect
        out[n, 1] = 0.0 if np.isnan(cos) else cos
    return out


_UNIT_SQUARE = np.array([[-0.5, -0.5], [0.5, -0.5], [0.5, 0.5], [-0.5, 0.5]])
"""A unit square about the origin, corners TL, TR, BR, BL."""
