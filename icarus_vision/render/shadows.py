"""Shadows of the objects on the ground plane z = 0, as an image-space mask.

TinyRenderer's shadow map darkens objects on objects, but the ground is no mesh (it is ray-cast in
:mod:`icarus_vision.render.backdrop`), so its shadows are drawn here. Every object is cut into
convex parts (the bars of a frame, a box, a polygonal sphere or cylinder), each given by points
whose convex hull it is. Under a directional light the shadow of a convex part on the ground is the
convex hull of its points slid along the light onto z = 0, and the image of that convex polygon is
the convex hull of their pixels: one ``cv2.fillConvexPoly`` per part, each filling the mask
(overlapping shadows add up to one shadow; no even-odd cancelling). A shadow reaching behind the
camera is first clipped, on the ground, to the camera's near plane, so it never wraps around.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from icarus_vision.render.camera import Camera, project_points, world_to_camera

_SHIFT = 4
"""Fractional bits of the polygon vertices given to OpenCV (1/16 pixel)."""
_MAX_PX = 1.0e6
"""Pixel coordinates beyond this are clipped first (OpenCV takes int32 fixed-point vertices)."""


def sphere_points(radius: float, n: int = 12) -> np.ndarray:
    """(n * (n // 2 - 1) + 2, 3) points on a sphere about the origin (a UV sphere's vertices)."""
    lat = np.pi * np.arange(1, n // 2) / (n // 2)
    lon = 2.0 * np.pi * np.arange(n) / n
    ring = np.stack(
        [np.outer(np.sin(lat), np.cos(lon)), np.outer(np.sin(lat), np.sin(lon))], axis=-1
    ).reshape(-1, 2)
    z = np.repeat(np.cos(lat), n)[:, None]
    pts = np.concatenate([ring, z], axis=1)
    return radius * np.concatenate([pts, [[0.0, 0.0, 1.0], [0.0, 0.0, -1.0]]])


def cylinder_points(radius: float, length: float, n: int = 16) -> np.ndarray:
    """(2n, 3) points on the rims of a cylinder about the local z axis, centred on the origin."""
    a = 2.0 * np.pi * np.arange(n) / n
    rim = np.stack([radius * np.cos(a), radius * np.sin(a)], axis=1)
    return np.concatenate([np.c_[rim, np.full(n, length / 2)], np.c_[rim, np.full(n, -length / 2)]])


def place(points: np.ndarray, pos, yaw: float) -> np.ndarray:
    """(..., 3) local points -> world, for a body at ``pos`` (3,) turned by ``yaw`` (rad) about z."""
    c, s = math.cos(yaw), math.sin(yaw)
    r = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    return np.asarray(points, dtype=float) @ r.T + np.asarray(pos, dtype=float)


def project_to_ground(points: np.ndarray, direction) -> np.ndarray:
    """Slide points along a light's direction onto the ground z = 0.

    Args:
        points: (..., 3) world points.
        direction: (3,) world direction towards the light, with a positive z.

    Returns:
        (..., 3) the points' shadows, z = 0.
    """
    d = np.asarray(direction, dtype=float)
    pts = np.asarray(points, dtype=float)
    return pts - (pts[..., 2:3] / d[2]) * d


def clip_polygon(poly: np.ndarray, plane: np.ndarray) -> np.ndarray:
    """Clip a convex polygon to the half-space ``plane[:3] . x + plane[3] >= 0``.

    Args:
        poly: (N, 3) vertices in order.
        plane: (4,) normal and offset.

    Returns:
        (M, 3) the clipped polygon's vertices in order (M = 0 when nothing is left).
    """
    s = poly @ plane[:3] + plane[3]
    inside = s >= 0.0
    if inside.all() or not inside.any():
        return poly if inside.all() else poly[:0]
    nxt, s_nxt = np.roll(poly, -1, axis=0), np.roll(s, -1)
    cross = inside != (s_nxt >= 0.0)
    t = np.divide(s, s - s_nxt, out=np.zeros_like(s), where=cross)
    hit = poly + t[:, None] * (nxt - poly)
    # Each edge keeps its start vertex when inside, then its crossing point when it crosses.
    keep = np.stack([inside, cross], axis=1).ravel()
    return np.stack([poly, hit], axis=1).reshape(-1, 3)[keep]


def _view_planes(camera: Camera) -> np.ndarray:
    """(5, 4) camera-frame half-spaces: the near plane and a pyramid three times the image wide."""
    k = camera.K
    f, w, h = k[0, 0], camera.width, camera.height
    cx, cy = k[0, 2], k[1, 2]
    return np.array([
        [0.0, 0.0, 1.0, -camera.near],
        [f, 0.0, cx + w, 0.0],  # u >= -w
        [-f, 0.0, 2.0 * w - cx, 0.0],  # u <= 2w
        [0.0, f, cy + h, 0.0],  # v >= -h
        [0.0, -f, 2.0 * h - cy, 0.0],  # v <= 2h
    ])  # fmt: skip


def _fill(mask: np.ndarray, pixels: np.ndarray) -> None:
    """Fill the convex hull of (N, 2) pixels into ``mask`` (1 inside)."""
    hull = cv2.convexHull(np.round(pixels * (1 << _SHIFT)).astype(np.int32))
    cv2.fillConvexPoly(mask, hull, 1, cv2.LINE_8, _SHIFT)


def ground_shadow_mask(
    points: np.ndarray,
    starts: np.ndarray,
    direction,
    camera: Camera,
    r_world_cam: np.ndarray,
    t_world_cam: np.ndarray,
) -> np.ndarray | None:
    """Where the ground seen in the image lies in the shadow of the objects.

    Args:
        points: (M, 3) world points of every convex part, part after part.
        starts: (P,) index in ``points`` of each part's first point, increasing.
        direction: (3,) world direction towards the light.
        camera: the camera of the frame.
        r_world_cam: (3, 3) camera rotation; t_world_cam: (3,) camera centre (world).

    Returns:
        (H, W) uint8 mask, 1 where the ground point on the pixel's ray is in shadow (whatever the
        pixel shows), or None when no shadow falls in the image or the light is not above the
        horizon.
    """
    d = np.asarray(direction, dtype=float)
    if d[2] <= 0.0 or len(starts) == 0:
        return None
    k = camera.K
    h, w = camera.height, camera.width
    starts = np.asarray(starts)
    ground = project_to_ground(points, d)
    cam = world_to_camera(ground, r_world_cam, t_world_cam)
    z = cam[:, 2]
    in_front = np.minimum.reduceat(z, starts) > camera.near
    uv, _ = project_points(k, cam)  # NaN behind the camera: such parts are clipped below
    lo, hi = np.minimum.reduceat(uv, starts), np.maximum.reduceat(uv, starts)
    sane = (np.abs(lo).max(axis=1) < _MAX_PX) & (np.abs(hi).max(axis=1) < _MAX_PX)
    overlaps = (
        (hi[:, 0] >= -0.5) & (lo[:, 0] <= w - 0.5) & (hi[:, 1] >= -0.5) & (lo[:, 1] <= h - 0.5)
    )
    direct = in_front & sane & overlaps
    # Parts reaching behind the near plane (or absurdly far out): clip their ground polygon first.
    clipped = ~(in_front & sane) & (np.maximum.reduceat(z, starts) > camera.near)
    if not (direct.any() or clipped.any()):
        return None
    ends = np.append(starts[1:], len(points))
    mask = np.zeros((h, w), np.uint8)
    for i in np.flatnonzero(direct):
        _fill(mask, uv[starts[i] : ends[i]])
    planes = _view_planes(camera) if clipped.any() else None
    for i in np.flatnonzero(clipped):
        hull = cv2.convexHull(ground[starts[i] : ends[i], :2].astype(np.float32))[:, 0]
        poly = world_to_camera(np.c_[hull, np.zeros(len(hull))], r_world_cam, t_world_cam)
        for plane in planes:
            poly = clip_polygon(poly, plane)
        if len(poly) >= 3:
            _fill(mask, project_points(k, poly)[0])
    return mask if mask.any() else None
