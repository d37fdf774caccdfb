from __future__ import annotations

import numpy as np

from icarus_vision.render.backdrop import (
    GROUND_ID,
    SKY_ID,
    blend_reflection,
    paint_backdrop,
    ray_norms,
    shade_factor,
)
from icarus_vision.render.camera import Camera
from icarus_vision.render.textures import Material, texture_image

LEVEL = np.array([0.0, 0.0, 0.0, 1.0])


def _paint(shadow: np.ndarray | None):
    """A level camera 2 m up; an object (body 5) covers a square across the horizon."""
    cam = Camera(width=64, height=48, uptilt_deg=0.0)
    rgb = np.zeros((48, 64, 3), np.uint8)
    rgb[10:40, 20:40] = (200, 100, 50)
    seg = np.full((48, 64), SKY_ID, np.int32)
    seg[10:40, 20:40] = 5
    depth = np.full((48, 64), cam.far, np.float32)
    r, t = cam.pose(np.array([0.0, 0.0, 2.0]), LEVEL)
    tex = texture_image(Material("checker", (0.6, 0.5, 0.4), (0.3, 0.3, 0.3), 1.0))
    sky = np.full((48, 64, 3), 77, np.uint8)
    direction, color = (0.2, 0.1, 1.0), (1.0, 0.9, 0.8)
    gain = shade_factor(direction, color, 0.5, 0.45)
    dark = shade_factor(direction, color, 0.5, 0.0)
    paint_backdrop(rgb, seg, depth, cam, ray_norms(cam), r, t, tex, 1.0, gain, sky, shadow, dark)
    return rgb, seg, gain, dark


def test_shadow_darkens_only_ground_pixels_to_the_ambient_gain():
    plain, seg, gain, dark = _paint(None)
    everywhere = np.ones(seg.shape, np.uint8)
    shaded, seg2, _, _ = _paint(everywhere)
    np.testing.assert_array_equal(seg, seg2)
    keep = seg != GROUND_ID  # sky and the object
    np.testing.assert_array_equal(shaded[keep], plain[keep])
    assert (seg == SKY_ID).any() and (seg == 5).any() and (seg == GROUND_ID).any()
    ground = seg == GROUND_ID
    ratio = shaded[ground].reshape(-1, 3).mean(axis=0) / plain[ground].reshape(-1, 3).mean(axis=0)
    np.testing.assert_allclose(ratio, dark / gain, atol=0.02)


def test_shadow_mask_is_honoured_pixel_by_pixel():
    plain, seg, _, _ = _paint(None)
    mask = np.zeros(seg.shape, np.uint8)
    mask[:, :32] = 1
    shaded, _, _, _ = _paint(mask)
    changed = (shaded != plain).any(axis=-1)
    assert changed[:, :32].any() and not changed[:, 32:].any()
    assert not changed[seg != GROUND_ID].any()


def test_a_reflection_blends_into_the_floor_where_it_shows_an_object():
    rgb = np.full((20, 30, 3), 100, np.uint8)
    floor = np.zeros((20, 30), bool)
    floor[10:] = True  # the lower half is floor
    mirror = np.zeros_like(rgb)
    mirror[:, 10:20] = (250, 0, 0)
    hit = np.zeros_like(floor)
    hit[:, 10:20] = True  # a red object in the reflection, above and below the floor's edge
    sharp = rgb.copy()
    blend_reflection(sharp, floor, mirror, hit, 0.4)
    np.testing.assert_array_equal(sharp[10:, 10:20], np.broadcast_to([160, 60, 60], (10, 10, 3)))
    changed = (sharp != rgb).any(axis=2)
    np.testing.assert_array_equal(changed, floor & hit)  # only floor pixels with a reflection
    rough = rgb.copy()
    blend_reflection(rough, floor, mirror, hit, 0.4, blur_px=1.5)
    changed = (rough != rgb).any(axis=2)
    assert (changed <= floor).all() and changed[10:, 8].all() and not changed[10:, :5].any()
    assert (rough[changed][:, 0] >= 100).all()  # redder, never darkened by the empty reflection
