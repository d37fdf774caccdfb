from __future__ import annotations

from pathlib import Path

import numpy as np
import pybullet as p
import pytest

from icarus_vision.render import egl
from icarus_vision.render.backdrop import GROUND_ID, SKY_ID
from icarus_vision.render.camera import Camera
from icarus_vision.render.labels import frame_labels
from icarus_vision.render.randomize import load_recipe, sample_visuals
from icarus_vision.render.scene import Distractor, Lighting, Scene
from icarus_vision.sim.dynamics import rpy_to_quat
from icarus_vision.sim.random_track import random_track
from icarus_vision.sim.track import Gate, Track

LEVEL = np.array([0.0, 0.0, 0.0, 1.0])
EYE = np.array([0.0, 0.0, 2.0])

RECIPE = Path(__file__).resolve().parents[2] / "datasets" / "gates-v1.toml"


def _is_gate_red(rgb: np.ndarray) -> np.ndarray:
    rgb = rgb.astype(int)
    return (rgb[..., 0] > 80) & (rgb[..., 1] < 30) & (rgb[..., 2] < 30)


def test_gate_straight_ahead_lands_where_k_says(one_gate_scene):
    scene = one_gate_scene
    frame = scene.render(EYE, LEVEL)
    assert frame.rgb.shape == (240, 320, 3) and frame.rgb.dtype == np.uint8
    corners, _ = scene.camera.project(scene.track.gates[0].corners(), EYE, LEVEL)
    # 1 m opening at 4 m with f = 160 px: corners at (139.5, 99.5) ... (179.5, 139.5).
    np.testing.assert_allclose(corners[0], [139.5, 99.5])
    red = _is_gate_red(frame.rgb)
    gate = frame.seg == scene.gate_bodies[0]
    # The frame bar starts right outside each corner, diagonally, and the opening right inside.
    for (u, v), (du, dv) in zip(corners, [(-1, -1), (1, -1), (1, 1), (-1, 1)], strict=True):
        ui, vi = int(u + 0.5 * du), int(v + 0.5 * dv)  # the pixel just outside the corner
        assert gate[vi, ui] and red[vi, ui]
        assert not gate[int(v - 0.5 * dv), int(u - 0.5 * du)]  # the pixel just inside
    assert not red[119, 159] and frame.seg[119, 159] in (SKY_ID, GROUND_ID)
    # Opening edges from the mask match the projection to the pixel.
    row, col = gate[119], gate[:, 159]
    assert row[139] and not row[140] and not row[179] and row[180]
    assert col[99] and not col[100] and not col[139] and col[140]


def test_ground_below_and_sky_above_horizon(one_gate_scene):
    frame = one_gate_scene.render(EYE, LEVEL)
    assert frame.seg[0, 0] == SKY_ID and frame.seg[-1, 0] == GROUND_ID
    sky = np.round(np.multiply(one_gate_scene.style.background.color, 255))
    np.testing.assert_array_equal(frame.rgb[0, 0], sky)
    assert frame.rgb[-1, 0, 1] > frame.rgb[-1, 0, 2]  # the default ground is green
    # Bottom row looks down 36.9 deg from 2 m: ground at 2 / tan(36.9) m ahead.
    assert frame.depth[-1, 160] == pytest.approx(2.0 / (120.5 / 160.0), rel=0.02)


def test_gate_flown_twice_is_built_once():
    gates = (Gate((5.0, 0.0, 2.0)), Gate((10.0, 5.0, 2.0), 90.0), Gate((5.0, 0.0, 2.0), 180.0))
    track = Track("loop", gates, start_pos=(0.0, 0.0, 0.2))
    with Scene(track) as scene:
        assert len(scene.gate_bodies) == 2
        assert p.getNumBodies(physicsClientId=scene.client) == 2


def test_scenes_use_their_own_clients():
    track = Track("one", (Gate((4.0, 0.0, 2.0)),))
    with (
        Scene(track) as a,
        Scene(track, distractors=(Distractor("box", (6, 2, 1), (1, 1, 1)),)) as b,
    ):
        assert a.client != b.client
        assert p.getNumBodies(physicsClientId=a.client) == 1
        assert p.getNumBodies(physicsClientId=b.client) == 2
    assert a.client == -1


def test_same_seed_renders_identical_images():
    recipe = load_recipe(RECIPE)
    images = []
    for _ in range(2):
        rng = np.random.default_rng(7)
        track = random_track(4, seed=rng)
        vis = sample_visuals(recipe, rng, track)
        with Scene(track, vis.camera, vis.style, vis.distractors) as scene:
            pos = np.asarray(track.gates[0].pos) - 3.0 * track.gates[0].normal
            frame = scene.render(pos, LEVEL, vis.lighting)
            labels = frame_labels(scene, frame, pos, LEVEL)
        images.append((frame.rgb, frame.seg, [lab.corners_px for lab in labels]))
    np.testing.assert_array_equal(images[0][0], images[1][0])
    np.testing.assert_array_equal(images[0][1], images[1][1])
    assert len(images[0][2]) >= 1
    for a, b in zip(images[0][2], images[1][2], strict=True):
        np.testing.assert_array_equal(a, b)


def test_every_distractor_shape_and_shadows_render():
    shapes = ("box", "cylinder", "sphere", "frame", "arch", "pole")
    ds = tuple(
        Distractor(s, (6.0, -3.0 + 1.2 * i, 1.0), (0.6, 0.4, 0.1)) for i, s in enumerate(shapes)
    )
    track = Track("one", (Gate((4.0, 0.0, 2.0)),))
    with Scene(track, Camera(hfov_deg=120.0, uptilt_deg=0.0), distractors=ds) as scene:
        frame = scene.render(EYE - [0, 0, 1.0], LEVEL, Lighting(shadows=True))
        seen = set(np.unique(frame.seg)) & set(scene.distractor_bodies)
        assert seen == set(scene.distractor_bodies)


@pytest.mark.parametrize("plugin", [None, "missing-plugin.so"], ids=["absent", "unloadable"])
def test_egl_request_falls_back_to_tiny_renderer_where_the_plugin_is_unavailable(
    monkeypatch, tmp_path, plugin
):
    path = None if plugin is None else str(tmp_path / plugin)
    monkeypatch.setattr(egl, "egl_plugin_path", lambda: path)
    with pytest.warns(UserWarning, match="EGL rendering unavailable.*using TinyRenderer"):
        scene = Scene(Track("one", (Gate((4.0, 0.0, 2.0)),)), egl=True)
    with scene:
        assert scene.renderer == "tiny"
        assert scene.render(EYE, LEVEL).rgb.shape == (240, 320, 3)


def test_egl_and_tiny_renderers_agree_on_the_masks(make_scene):
    """The same scenes (every distractor shape, textures, random tracks) seen by both renderers."""
    recipe = load_recipe(RECIPE)
    rng = np.random.default_rng(5)
    shapes = ("box", "cylinder", "sphere", "frame", "arch", "pole")
    ds = tuple(
        Distractor(s, (6.0, -4.0 + 1.6 * i, 1.0), (0.6, 0.4, 0.1)) for i, s in enumerate(shapes)
    )
    for _ in range(2):
        track = random_track(5, seed=rng)
        vis = sample_visuals(recipe, rng, track)
        gates = track.gates[:3]
        yaws = rpy_to_quat(np.array([[0.0, 0.0, g.yaw] for g in gates]))
        poses = [(np.asarray(g.pos) - 4.0 * g.normal, q) for g, q in zip(gates, yaws, strict=True)]
        poses.append((EYE - [0.0, 0.0, 1.0], LEVEL))
        frames = {}
        for renderer in ("tiny", "egl"):
            args = (track, vis.camera, vis.style, vis.distractors + ds)
            with make_scene(renderer, *args) as scene:
                frames[renderer] = [scene.render(pos, q, vis.lighting) for pos, q in poses]
        for tiny, gl in zip(frames["tiny"], frames["egl"], strict=True):
            a, b = tiny.seg >= 0, gl.seg >= 0
            both = a & b
            assert a.sum() > 500 and both.sum() / (a | b).sum() > 0.95
            assert np.mean(tiny.seg[both] == gl.seg[both]) > 0.99  # the same bodies
            np.testing.assert_allclose(gl.depth[both], tiny.depth[both], rtol=0.01)
            np.testing.assert_array_equal(tiny.seg[~a & ~b], gl.seg[~a & ~b])  # ground and sky
