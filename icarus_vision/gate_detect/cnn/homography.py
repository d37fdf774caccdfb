"""Homographies of a frame's few quadrilaterals, compiled (numba): the refiner and the zoom stage
need a handful per frame, and one OpenCV or numpy call per matrix cost more than the maths.

:func:`perspective` computes exactly what ``cv2.getPerspectiveTransform`` does (the same 8x8
system from float32 points, solved by the same LU elimination in float64: bit for bit the same
matrices), for all quadrilaterals in one call. Where that system is singular (three corners in
a line), OpenCV falls back on another solver; this returns a null homography instead (callers
check their quadrilaterals first: ``rectify.usable``).
"""

from __future__ import annotations

import numpy as np
from numba import njit

SINGULAR_PIVOT = 10 * np.finfo(np.float64).eps
"""A pivot below this makes the system singular (OpenCV's LU threshold); the homography is then
all zero but its last element."""


def perspective(src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """(N, 3, 3) homographies taking (4, 2) ``src`` corners onto ``dst`` corners, either side
    (N, 4, 2) or one (4, 2) shared by all (as ``cv2.getPerspectiveTransform``, from float32
    points)."""
    src = np.asarray(src, np.float32).reshape(-1, 4, 2)
    dst = np.asarray(dst, np.float32).reshape(-1, 4, 2)
    if len(src) != len(dst) and 1 not in (len(src), len(dst)):
        raise ValueError(f"{len(src)} source and {len(dst)} destination quadrilaterals")
    if not len(src) or not len(dst):
        return np.zeros((0, 3, 3))
    return _perspective(src, dst)


@njit(cache=True)
def _perspective(src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    n = max(len(src), len(dst))
    out = np.zeros((n, 3, 3))
    a, b = np.empty((8, 8)), np.empty(8)
    for g in range(n):
        s, d = src[g % len(src)], dst[g % len(dst)]
        for i in range(4):  # OpenCV's system, its products in float32 (of Point2f)
            sx, sy, dx, dy = s[i, 0], s[i, 1], d[i, 0], d[i, 1]
            a[i, 0] = a[i + 4, 3] = sx
            a[i, 1] = a[i + 4, 4] = sy
            a[i, 2] = a[i + 4, 5] = 1.0
            a[i, 3] = a[i, 4] = a[i, 5] = a[i + 4, 0] = a[i + 4, 1] = a[i + 4, 2] = 0.0
            a[i, 6], a[i, 7] = -sx * dx, -sy * dx
            a[i + 4, 6], a[i + 4, 7] = -sx * dy, -sy * dy
            b[i], b[i + 4] = dx, dy
        out[g, 2, 2] = 1.0
        if _lu_solve(a, b):
            for i in range(8):
                out[g, i // 3, i % 3] = b[i]
    return out


@njit(cache=True)
def _lu_solve(a: np.ndarray, b: np.ndarray) -> bool:
    """Solve a x = b in place (x into ``b``) by Gaussian elimination with partial pivoting, in
    OpenCV's order of operations; False if singular."""
    m = len(b)
    for i in range(m):
        k = i
        for j in range(i + 1, m):
            if abs(a[j, i]) > abs(a[k, i]):
                k = j
        if abs(a[k, i]) < SINGULAR_PIVOT:
            return False
        if k != i:
            for j in range(i, m):
                a[i, j], a[k, j] = a[k, j], a[i, j]
            b[i], b[k] = b[k], b[i]
        d = -1.0 / a[i, i]
        for j in range(i + 1, m):
            alpha = a[j, i] * d
            for k in range(i + 1, m):
                a[j, k] += alpha * a[i, k]
            b[j] += alpha * b[i]
    for i in range(m - 1, -1, -1):
        s = b[i]
        for k in range(i + 1, m):
            s -= a[i, k] * b[k]
        b[i] = s / a[i, i]
    return True


def transform(h: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """Apply (N, 3, 3) homographies to (N, K, 2) points (inf or NaN where a point maps to
    infinity)."""
    h = np.ascontiguousarray(h, np.float64)
    pts = np.ascontiguousarray(pts, np.float64)
    if h.shape[0] != pts.shape[0] or h.shape[1:] != (3, 3) or pts.shape[2:] != (2,):
        raise ValueError(f"expected (N, 3, 3) and (N, K, 2), got {h.shape} and {pts.shape}")
    return _transform(h, pts)


@njit(cache=True, error_model="numpy")
def _transform(h: np.ndarray, pts: np.ndarray) -> np.ndarray:
    out = np.empty_like(pts)
    for n in range(len(pts)):
        for k in range(pts.shape[1]):
            out[n, k, 0], out[n, k, 1] = apply(h[n], pts[n, k, 0], pts[n, k, 1])
    return out


@njit(cache=True, error_model="numpy")
def apply(m: np.ndarray, x: float, y: float) -> tuple[float, float]:
    """A (3, 3) homography applied to one point (compiled code's :func:`transform`)."""
    w = x * m[2, 0] + y * m[2, 1] + m[2, 2]
    return (x * m[0, 0] + y * m[0, 1] + m[0, 2]) / w, (x * m[1, 0] + y * m[1, 1] + m[1, 2]) / w
