"""View-frustum culling agrees with the pinhole projection."""

from __future__ import annotations

import numpy as np

from icarus_vision.render.camera import Camera
from icarus_vision.render.frustum import spheres_in_view


def test_points_in_image_are_in_view_and_far_outside_are_not():
    cam = Camera(uptilt_deg=0.0)
    rng = np.random.default_rng(0)
    r_wc, t_wc = cam.pose(np.zeros(3), np.array([0.0, 0.0, 0.0, 1.0]))
    pts = rng.uniform(-20, 20, (2000, 3))
    px, z = cam.project(pts, np.zeros(3), np.array([0.0, 0.0, 0.0, 1.0]))
    in_image = cam.in_image(px) & (z > 0)
    tiny = spheres_in_view(cam, r_wc[None], t_wc[None], pts, np.full(len(pts), 1e-6))[0]
    assert np.array_equal(tiny, in_image)
    # A sphere reaching into the image is in view; its centre may lie outside.
    big = spheres_in_view(cam, r_wc[None], t_wc[None], pts, np.full(len(pts), 3.0))[0]
    assert np.all(big[in_image]) and big.sum() > in_image.sum()
