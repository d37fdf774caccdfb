"""Ground shadows checked against ray casting: a ground point is in shadow when the ray from it
towards the light meets the object."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from icarus_vision.render.backdrop import GROUND_ID, SKY_ID
from icarus_vision.render.camera import Camera
from icarus_vision.render.meshes import box_corners, box_mesh
from icarus_vision.render.scene import RENDERERS, Distractor, Lighting, Scene, SceneStyle
from icarus_vision.render.shadows import (
    clip_polygon,
    cylinder_points,
    ground_shadow_mask,
    project_to_ground,
    sphere_points,
)
from icarus_vision.render.textures import Material
from icarus_vision.sim.dynamics import rpy_to_quat
from icarus_vision.sim.track import Gate, Track

DOWN = rpy_to_quat(np.array([[0.0, np.pi / 2, 0.0]]))[0]  # nose (and camera) straight down
LEVEL = np.array([0.0, 0.0, 0.0, 1.0])
OBLIQUE = (0.5, 0.3, 1.0)
CAM = Camera(uptilt_deg=0.0)
STYLE = SceneStyle(ground=Material("solid", (0.5, 0.5, 0.5)))
BOX_LIMITS = (np.array([-0.25, 0.5, 1.5]), np.array([1.25, 1.5, 3.5]))
"""Low and high corner of the box distractor of the scene tests."""


def _ground_points(camera: Camera, pos, quat) -> tuple[np.ndarray, np.ndarray]:
    """World point where each pixel's ray meets z = 0: (H, W, 3), and (H, W) bool where it does."""
    r, t = camera.pose(pos, quat)
    k = camera.K
    u, v = np.meshgrid(np.arange(camera.width), np.arange(camera.height))
    rays = np.stack([(u - k[0, 2]) / k[0, 0], (v - k[1, 2]) / k[1, 1], np.ones(u.shape)], -1) @ r.T
    with np.errstate(divide="ignore", invalid="ignore"):
        s = -t[2] / rays[..., 2]
    return t + s[..., None] * rays, s > 0


def _box_shadow(points: np.ndarray, lo, hi, direction) -> np.ndarray:
    """(...) bool: the ray from each ground point towards the light meets the box [lo, hi]."""
    d = np.asarray(direction, dtype=float)
    with np.errstate(divide="ignore", invalid="ignore"):
        a, b = (np.asarray(lo) - points) / d, (np.asarray(hi) - points) / d
    near = np.nanmax(np.minimum(a, b), axis=-1)
    far = np.nanmin(np.maximum(a, b), axis=-1)
    return (near <= far) & (far > 0)


def _within_a_pixel(mask: np.ndarray, truth: np.ndarray, where: np.ndarray) -> None:
    """``mask`` equals ``truth`` on ``where`` except on pixels next to the truth's edge."""
    pad = np.pad(truth, 1, mode="edge")
    h, w = truth.shape
    shifts = [
        pad[1 + dv : 1 + dv + h, 1 + du : 1 + du + w] for dv in (-1, 0, 1) for du in (-1, 0, 1)
    ]
    edge = np.any(shifts, axis=0) & ~np.all(shifts, axis=0)
    wrong = (mask != truth) & where & ~edge
    assert not wrong.any(), f"{wrong.sum()} pixels off by more than one pixel"
    assert (mask & truth & where).sum() > 0.8 * (truth & where).sum()


def _box_distractors() -> tuple[Distractor, ...]:
    lo, hi = BOX_LIMITS
    return (Distractor("box", tuple((lo + hi) / 2), tuple(hi - lo), 0.0, Material("solid")),)


def _box(center, size) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(1, 8, 3) corners of an axis-aligned box, its low and its high corner."""
    c, h = np.asarray(center, dtype=float), np.asarray(size, dtype=float) / 2
    return box_corners(box_mesh(c, h)), c - h, c + h


def test_points_slide_along_the_light_onto_the_ground():
    pts = np.array([[1.0, 2.0, 3.0], [0.0, 0.0, 0.0]])
    np.testing.assert_allclose(project_to_ground(pts, (1.0, 0.0, 1.0)), [[-2, 2, 0], [0, 0, 0]])
    np.testing.assert_allclose(project_to_ground(pts[:1], (0.0, 0.0, 5.0)), [[1, 2, 0]])


def test_clip_polygon_keeps_the_inside_part_in_order():
    square = np.array([[0.0, 0.0, 0.0], [2.0, 0.0, 0.0], [2.0, 2.0, 0.0], [0.0, 2.0, 0.0]])
    half = clip_polygon(square, np.array([-1.0, 0.0, 0.0, 1.0]))  # x <= 1
    np.testing.assert_allclose(half, [[0, 0, 0], [1, 0, 0], [1, 2, 0], [0, 2, 0]])
    assert len(clip_polygon(square, np.array([1.0, 0.0, 0.0, 5.0]))) == 4
    assert len(clip_polygon(square, np.array([1.0, 0.0, 0.0, -5.0]))) == 0


def test_round_parts_hug_their_shapes():
    s = sphere_points(2.0)
    np.testing.assert_allclose(np.linalg.norm(s, axis=1), 2.0)
    assert s[:, 2].max() == pytest.approx(2.0) and s[:, 2].min() == pytest.approx(-2.0)
    c = cylinder_points(0.5, 3.0)
    np.testing.assert_allclose(np.linalg.norm(c[:, :2], axis=1), 0.5)
    assert set(np.round(c[:, 2], 9)) == {-1.5, 1.5}


@pytest.mark.parametrize("direction", [(0.0, 0.0, 1.0), OBLIQUE, (-0.8, 0.6, 0.5)])
def test_mask_of_a_box_seen_from_above_is_its_shadow(direction):
    eye = np.array([1.0, 0.5, 7.0])
    parts, lo, hi = _box((0.5, 1.0, 2.5), (1.5, 1.0, 2.0))
    r, t = CAM.pose(eye, DOWN)
    mask = ground_shadow_mask(parts.reshape(-1, 3), np.array([0]), direction, CAM, r, t)
    ground, hit = _ground_points(CAM, eye, DOWN)
    assert hit.all()
    truth = _box_shadow(ground, lo, hi, direction)
    assert truth.sum() > 600
    _within_a_pixel(mask.view(bool), truth, hit)


def test_parts_behind_the_camera_are_clipped_not_wrapped():
    """A tall box behind a low camera; the light from behind throws its shadow into the view."""
    eye = np.array([0.0, 0.0, 1.0])
    view = rpy_to_quat(np.array([[0.0, 0.3, 0.0]]))[0]
    boxes = [_box((-1.0, 0.0, 3.0), (0.4, 0.6, 6.0)), _box((-2.0, 1.0, 1.0), (0.5, 0.5, 2.0))]
    light = (-0.6, 0.1, 0.4)
    r, t = CAM.pose(eye, view)
    points = np.concatenate([b[0].reshape(-1, 3) for b in boxes])
    mask = ground_shadow_mask(points, np.array([0, 8]), light, CAM, r, t)
    ground, hit = _ground_points(CAM, eye, view)
    truth = np.any([_box_shadow(ground, lo, hi, light) for _, lo, hi in boxes], axis=0)
    assert (truth & hit).sum() > 400
    _within_a_pixel(mask.view(bool), truth, hit)


def test_no_mask_for_a_light_below_the_horizon_or_a_shadow_out_of_view():
    parts, _, _ = _box((0.0, 0.0, 2.0), (1.0, 1.0, 1.0))
    r, t = CAM.pose(np.array([-5.0, 0.0, 2.0]), LEVEL)
    args = (parts.reshape(-1, 3), np.array([0]))
    assert ground_shadow_mask(*args, (0.3, 0.0, -1.0), CAM, r, t) is None
    assert ground_shadow_mask(*args, (0.3, 0.0, 0.0), CAM, r, t) is None
    assert ground_shadow_mask(*args, (0.3, 0.0, 1.0), CAM, r, t) is not None
    r_back, _ = CAM.pose(t, rpy_to_quat(np.array([[0.0, 0.0, np.pi]]))[0])  # looking away
    assert ground_shadow_mask(*args, (0.3, 0.0, 1.0), CAM, r_back, t) is None


@pytest.mark.parametrize("renderer", RENDERERS)
def test_scene_darkens_the_ground_in_the_box_shadow_to_its_ambient_share(make_scene, renderer):
    eye = np.array([1.0, 0.5, 8.0])
    light = Lighting(direction=OBLIQUE, ambient=0.5, diffuse=0.4)
    track = Track("t", (Gate((30.0, 0.0, 2.0)),))
    with make_scene(renderer, track, CAM, STYLE, _box_distractors()) as scene:
        lit = scene.render(eye, DOWN, light)
        shaded = scene.render(eye, DOWN, dataclasses.replace(light, shadows=True))
    ground = (lit.seg == GROUND_ID) & (shaded.seg == GROUND_ID)
    dark = (shaded.rgb.astype(int) < lit.rgb).all(axis=-1) & ground
    points, _ = _ground_points(CAM, eye, DOWN)
    truth = _box_shadow(points, *BOX_LIMITS, OBLIQUE)
    _within_a_pixel(dark, truth, ground)
    n_dot_l = OBLIQUE[2] / np.linalg.norm(OBLIQUE)
    ratio = shaded.rgb[dark].astype(float).mean() / lit.rgb[dark].astype(float).mean()
    assert ratio == pytest.approx(0.5 / (0.5 + 0.4 * n_dot_l), abs=0.01)
    np.testing.assert_array_equal(shaded.rgb[~dark & ground], lit.rgb[~dark & ground])


def test_scene_shadows_leave_sky_alone_and_need_a_light_above_the_horizon():
    eye = np.array([-4.0, 1.0, 1.5])
    view = rpy_to_quat(np.array([[0.0, 0.1, 0.0]]))[0]
    gate = Gate((1.0, 1.0, 2.0))
    with Scene(Track("t", (gate,)), Camera(), STYLE, _box_distractors()) as scene:
        for direction in ((-0.5, 0.0, 0.6), (0.3, 0.2, -1.0)):
            light = Lighting(direction=direction)
            plain = scene.render(eye, view, light)
            shaded = scene.render(eye, view, dataclasses.replace(light, shadows=True))
            sky = plain.seg == SKY_ID
            assert sky.any() and (shaded.seg == plain.seg).all()
            np.testing.assert_array_equal(shaded.rgb[sky], plain.rgb[sky])
            ground = plain.seg == GROUND_ID
            changed = (shaded.rgb != plain.rgb).any(axis=-1) & ground
            assert changed.any() == (direction[2] > 0)
