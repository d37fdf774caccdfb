"""Shrinking a frame with OpenCV's ``INTER_AREA`` weights, faster at the detector's ratios.

The corner network reads the 320x240 frame at 256x192: an area resize by 5:4 on both axes,
which ``cv2.resize`` computes on a general path (per-pixel weight tables) in about 0.8 ms on an
AMD EPYC core, the largest cost of a frame outside the networks. Between one and two input
pixels per output pixel, each output pixel spans exactly two input pixels for most ratios, with
weights that repeat every ``p`` input (``q`` output) pixels: at 5:4, (0.8, 0.2), (0.6, 0.4),
(0.4, 0.6), (0.2, 0.8). So the resize is a few weighted sums of whole strided rows (one
``cv2.addWeighted`` per phase and axis; the columns on the transposed frame), in float32 and
rounded once at the end, as ``INTER_AREA`` does, in less than half the time (README,
Performance). The sums' float rounding differs from OpenCV's, which at some ratios moves a pixel
in a few hundred by one grey level (6:5, 10:9, or 4:3 on one axis only); at the ratios of
:data:`EXACT_RATIOS`, the same on both axes, the output is OpenCV's byte for byte on every test
image (random and rendered ones: tests). Other ratios and shapes fall back to ``cv2.resize``.
"""

from __future__ import annotations

import functools
import math
from fractions import Fraction

import cv2
import numpy as np

EXACT_RATIOS = frozenset({(5, 4), (4, 3), (3, 2)})
"""Shrinking ratios (input : output pixels, on both axes) computed by phases: those whose
output equals ``cv2.resize``'s exactly."""

Taps = tuple[int, int, tuple[tuple[int, float, float], ...]]
"""Along one axis: (p, q, per output phase (first input pixel in the period, its weight, the
next pixel's weight)); the pattern repeats every p input and q output pixels."""


@functools.cache
def area_taps(n_in: int, n_out: int) -> Taps | None:
    """``INTER_AREA``'s weights from ``n_in`` to ``n_out`` pixels along one axis, where every
    output pixel spans exactly two input pixels (:data:`Taps`); None where one does not (no
    shrinking, shrinking by 2 or more, or a ratio where some output pixel spans three)."""
    if not n_out < n_in < 2 * n_out:
        return None
    g = math.gcd(n_in, n_out)
    p, q = n_in // g, n_out // g
    scale = Fraction(p, q)
    phases = []
    for j in range(q):
        start, end = j * scale, (j + 1) * scale
        k = math.floor(start)
        if math.ceil(end) - k != 2:
            return None
        phases.append((k, float((k + 1 - start) / scale), float((end - k - 1) / scale)))
    return p, q, tuple(phases)


def area_resize(image: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """``cv2.resize(image, size, interpolation=cv2.INTER_AREA)`` of an (H, W, C) image to
    ``size`` (W, H): the same output, computed by phases (module docstring) for uint8 images
    shrunk by one of :data:`EXACT_RATIOS` on both axes in whole periods, else by ``cv2.resize``."""
    w_out, h_out = size
    h, w = image.shape[:2]
    tx, ty = area_taps(w, w_out), area_taps(h, h_out)
    fast = (
        image.ndim == 3 and image.dtype == np.uint8 and tx is not None and tx == ty
        and tx[:2] in EXACT_RATIOS and w % tx[0] == 0 and h % tx[0] == 0
    )  # fmt: skip
    if not fast:
        return cv2.resize(image, tuple(size), interpolation=cv2.INTER_AREA)
    c = image.shape[2]
    # columns first, as rows of the transposed frame, kept in float32; then the rows, rounded
    cols = _shrink_rows(cv2.transpose(image).reshape(w // tx[0], tx[0], h * c), tx, cv2.CV_32F)
    rows = cv2.transpose(cols.reshape(w_out, h, c)).reshape(h // ty[0], ty[0], w_out * c)
    return _shrink_rows(rows, ty, cv2.CV_8U).reshape(h_out, w_out, c)


def _shrink_rows(groups: np.ndarray, taps: Taps, depth: int) -> np.ndarray:
    """(G, p, L) rows in periods of p -> (G, q, L) weighted pairs of rows, float32
    (``depth`` ``cv2.CV_32F``) or rounded to uint8 (``cv2.CV_8U``)."""
    _, q, phases = taps
    out = np.empty(
        (groups.shape[0], q, groups.shape[2]), np.float32 if depth == cv2.CV_32F else np.uint8
    )
    for j, (k, a, b) in enumerate(phases):
        cv2.addWeighted(groups[:, k], a, groups[:, k + 1], b, 0.0, dst=out[:, j], dtype=depth)
    return out
