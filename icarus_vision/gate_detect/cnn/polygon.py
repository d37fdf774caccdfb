"""Overlap of quadrilaterals, compiled (numba): the decoder and the refiner's selection compare a
frame's candidate gates pairwise, and a compiled test costs a microsecond where OpenCV's
``convexHull`` / ``intersectConvexConvex`` / ``contourArea`` calls cost about 15.

A quadrilateral is (4, 2) float64 points; the overlap of two is that of their convex hulls
(a quadrilateral with a reflex corner, or a degenerate one, counts as its hull).
"""

from __future__ import annotations

import numpy as np
from numba import njit

BUFFER = 32
"""Vertices a polygon buffer holds: the intersection of two convex quadrilaterals has at most 8
(more only as repeated points where edges meet at a vertex; extra ones are dropped)."""


@njit(cache=True)
def convex_hull4(q: np.ndarray) -> tuple[np.ndarray, int]:
    """Convex hull of (4, 2) points, counter-clockwise (y up; clockwise on screen), by Andrew's
    monotone chain: ((BUFFER, 2) buffer, number of vertices: 0-2 if degenerate)."""
    pts = q.copy()
    for i in range(1, 4):  # insertion sort by x, then y
        j = i
        while j > 0 and (pts[j, 0] < pts[j - 1, 0]
                         or (pts[j, 0] == pts[j - 1, 0] and pts[j, 1] < pts[j - 1, 1])):  # fmt: skip
            x, y = pts[j, 0], pts[j, 1]
            pts[j, 0], pts[j, 1] = pts[j - 1, 0], pts[j - 1, 1]
            pts[j - 1, 0], pts[j - 1, 1] = x, y
            j -= 1
    hull = np.empty((BUFFER, 2))
    n = 0
    for half in range(2):  # lower chain left to right, then upper chain right to left
        start = n
        for k in range(4):
            i = k if half == 0 else 3 - k
            while n >= start + 2 and _cross(hull[n - 2], hull[n - 1], pts[i]) <= 0.0:
                n -= 1
            hull[n, 0], hull[n, 1] = pts[i, 0], pts[i, 1]
            n += 1
        n -= 1  # each chain's last point starts the other
    return hull, n if n >= 3 else 0


@njit(cache=True)
def mean_side(q: np.ndarray) -> float:
    """Mean side length of a (4, 2) quadrilateral (compiled; ``metrics.mean_side`` in numpy)."""
    s = 0.0
    for i in range(4):
        j = (i + 1) % 4
        s += np.sqrt((q[i, 0] - q[j, 0]) ** 2 + (q[i, 1] - q[j, 1]) ** 2)
    return s / 4


@njit(cache=True)
def _cross(o: np.ndarray, a: np.ndarray, b: np.ndarray) -> float:
    return (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])


@njit(cache=True)
def _area(poly: np.ndarray, n: int) -> float:
    """Area of the first ``n`` vertices of a polygon (shoelace)."""
    s = 0.0
    for i in range(n):
        j = (i + 1) % n
        s += poly[i, 0] * poly[j, 1] - poly[j, 0] * poly[i, 1]
    return abs(0.5 * s)


@njit(cache=True, error_model="numpy")
def _clip(subject: np.ndarray, n: int, clip: np.ndarray, m: int) -> tuple[np.ndarray, int]:
    """The part of a convex polygon inside another, both counter-clockwise (Sutherland-Hodgman):
    (buffer, vertices)."""
    out = subject.copy()
    for e in range(m):
        if n == 0:
            break
        a, b = clip[e], clip[(e + 1) % m]
        src = out.copy()
        k = 0
        for i in range(n):
            p, r = src[i], src[(i + 1) % n]
            dp, dr = _cross(a, b, p), _cross(a, b, r)
            if dp >= 0.0 and k < BUFFER:
                out[k, 0], out[k, 1] = p[0], p[1]
                k += 1
            if (dp >= 0.0) != (dr >= 0.0) and k < BUFFER:  # the edge crosses the line
                t = dp / (dp - dr)
                out[k, 0], out[k, 1] = p[0] + t * (r[0] - p[0]), p[1] + t * (r[1] - p[1])
                k += 1
        n = k
    return out, n


@njit(cache=True)
def quad_iou_kernel(a: np.ndarray, b: np.ndarray) -> float:
    """Intersection over union of two (4, 2) float64 quadrilaterals' convex hulls, in [0, 1]."""
    ha, na = convex_hull4(a)
    hb, nb = convex_hull4(b)
    area_a, area_b = _area(ha, na), _area(hb, nb)
    if na == 0 or nb == 0:
        inter = 0.0
    else:
        clipped, nc = _clip(ha, na, hb, nb)
        inter = _area(clipped, nc) if nc >= 3 else 0.0
    union = area_a + area_b - inter
    return min(inter / union, 1.0) if union > 0.0 else 0.0


def quad_iou(a: np.ndarray, b: np.ndarray) -> float:
    """Intersection over union of two (4, 2) quadrilaterals (their convex hulls), in [0, 1]."""
    return quad_iou_kernel(
        np.ascontiguousarray(a, np.float64).reshape(4, 2),
        np.ascontiguousarray(b, np.float64).reshape(4, 2),
    )
