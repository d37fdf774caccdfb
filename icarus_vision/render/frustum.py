"""View-frustum culling: can a sphere show in a camera's image? Conservative and batched."""

from __future__ import annotations

import math

import numpy as np

from icarus_vision.render.camera import Camera


def spheres_in_view(
    camera: Camera,
    r_world_cam: np.ndarray,
    t_world_cam: np.ndarray,
    centres: np.ndarray,
    radii: np.ndarray,
) -> np.ndarray:
    """Whether each sphere may intersect the view pyramid of each camera pose.

    The pyramid is bounded by the four planes through the camera centre and the outer image
    edges, and by the camera plane (z = 0 of the optical frame). False means the sphere cannot
    show in the image; True means it may (the test ignores the pyramid's edges and corners).

    Args:
        camera: intrinsics and resolution.
        r_world_cam: (N, 3, 3) camera rotations (columns: optical axes in the world frame).
        t_world_cam: (N, 3) camera centres, world frame.
        centres: (G, 3) sphere centres, world frame.
        radii: (G,) sphere radii, m.

    Returns:
        (N, G) bool.
    """
    r = np.asarray(r_world_cam, float).reshape(-1, 3, 3)
    t = np.asarray(t_world_cam, float).reshape(-1, 3)
    rad = np.asarray(radii, float)[None]
    c = np.einsum("ngk,nkj->ngj", np.asarray(centres, float)[None] - t[:, None], r)
    k = camera.K
    th, tv = 0.5 * camera.width / k[0, 0], 0.5 * camera.height / k[1, 1]
    x, y, z = c[..., 0], c[..., 1], c[..., 2]
    inside = z > -rad
    for a, tan in ((x, th), (-x, th), (y, tv), (-y, tv)):
        inside &= (a - tan * z) / math.sqrt(1.0 + tan * tan) < rad
    return inside
