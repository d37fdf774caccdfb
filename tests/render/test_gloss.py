"""Glossy floors (the gates-v4 recipe): the world mirrored through the floor is blended into the
floor pixels only, where the camera model puts the mirror image; masks, depth and labels stay as
they were; without a gloss nothing changes, not even the number of renders; and switching glossy
floors on in a recipe leaves every other draw alone."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pytest

from icarus_vision.dataset.layout import ShardSpec
from icarus_vision.dataset.shard import iter_samples
from icarus_vision.render import scene as scene_module
from icarus_vision.render.backdrop import GROUND_ID
from icarus_vision.render.camera import Camera
from icarus_vision.render.labels import frame_labels
from icarus_vision.render.randomize import load_recipe, sample_visuals
from icarus_vision.render.scene import Gloss, Lighting, Scene, SceneStyle
from icarus_vision.render.textures import Material
from icarus_vision.sim.dynamics import rpy_to_quat
from icarus_vision.sim.random_track import random_track
from icarus_vision.sim.track import Gate, Track

ROOT = Path(__file__).resolve().parents[2]
LEVEL = np.array([0.0, 0.0, 0.0, 1.0])
EYE = np.array([0.0, 0.0, 1.0])
GATE = Gate((5.0, 0.0, 1.0))  # red, at the camera's height: its mirror image is below the horizon
CAMERA = Camera(uptilt_deg=0.0)
DULL = Lighting(specular=0.0)  # no highlights: the red gate stays free of green and blue


def _scene(gloss: Gloss | None) -> Scene:
    style = SceneStyle(
        gate_materials=(Material("solid", (1.0, 0.0, 0.0)),),
        ground=Material("solid", (0.4, 0.4, 0.4)),
        gloss=gloss,
    )
    return Scene(Track("one", (GATE,), start_pos=(0.0, 0.0, 0.2)), CAMERA, style)


def _render(gloss: Gloss | None, pos=EYE, quat=LEVEL):
    with _scene(gloss) as scene:
        frame = scene.render(pos, quat, DULL)
        return frame, frame_labels(scene, frame, pos, quat)


def test_a_glossy_floor_mirrors_the_gate_where_the_camera_model_puts_it():
    k = 0.4
    matte, labels = _render(None)
    shiny, shiny_labels = _render(Gloss(k))
    np.testing.assert_array_equal(shiny.seg, matte.seg)
    np.testing.assert_array_equal(shiny.depth, matte.depth)
    assert len(labels) == len(shiny_labels) == 1
    np.testing.assert_array_equal(shiny_labels[0].corners_px, labels[0].corners_px)
    changed = (shiny.rgb != matte.rgb).any(axis=2)
    assert changed.sum() > 300 and (matte.seg[changed] == GROUND_ID).all()
    assert changed[: CAMERA.height // 2].sum() == 0  # all of it below the horizon
    # The middles of the bottom and top bars, mirrored through z = 0 and projected.
    half = GATE.size / 2 + GATE.frame_width / 2
    mirrored = np.array([[5.0, 0.0, -(1.0 - half)], [5.0, 0.0, -(1.0 + half)]])
    px, _ = CAMERA.project(mirrored, EYE, LEVEL)
    for u, v in np.rint(px).astype(int):
        floor, seen = matte.rgb[v, u].astype(float), shiny.rgb[v, u].astype(float)
        assert matte.seg[v, u] == GROUND_ID
        assert seen[0] > floor[0] + 10  # redder: a blend towards the gate's red ...
        np.testing.assert_allclose(seen[1:], (1.0 - k) * floor[1:], atol=1.0)  # ... with k of it
    # Floor pixels whose reflection shows nothing (the sky) keep their colour.
    u, v = np.rint(CAMERA.project(np.array([5.0, 3.0, -1.0]), EYE, LEVEL)[0]).astype(int)
    assert matte.seg[v, u] == GROUND_ID and not changed[v, u]


def test_a_rough_gloss_spreads_the_reflection_and_repeats():
    sharp, _ = _render(Gloss(0.4))
    rough, _ = _render(Gloss(0.4, blur_px=1.5))
    again, _ = _render(Gloss(0.4, blur_px=1.5))
    np.testing.assert_array_equal(rough.rgb, again.rgb)
    differ = (rough.rgb != sharp.rgb).any(axis=2)
    assert differ.any() and (sharp.seg[differ] == GROUND_ID).all()
    matte, _ = _render(None)
    spread = (rough.rgb != matte.rgb).any(axis=2).sum()
    assert spread > (sharp.rgb != matte.rgb).any(axis=2).sum()


@pytest.mark.parametrize(
    "gloss, quat, renders",
    [
        (None, LEVEL, 1),
        (Gloss(0.3), LEVEL, 2),
        (Gloss(0.3), rpy_to_quat(np.array([[0.0, -1.0, 0.0]]))[0], 1),  # looking up: no floor
    ],
    ids=["matte", "glossy", "glossy-no-floor-in-view"],
)
def test_the_second_render_is_made_only_where_a_glossy_floor_is_seen(
    monkeypatch, gloss, quat, renders
):
    calls = []
    real = scene_module.p.getCameraImage

    def counted(*args, **kwargs):
        calls.append(1)
        return real(*args, **kwargs)

    monkeypatch.setattr(scene_module.p, "getCameraImage", counted)
    _render(gloss, quat=quat)
    assert len(calls) == renders


def test_v4_draws_glossy_floors_in_halls_and_leaves_every_other_draw_alone():
    v3, v4 = load_recipe("gates-v3"), load_recipe("gates-v4")
    assert v4.hall.floor_gloss_prob > 0.0 and v3.hall.floor_gloss_prob == 0.0
    track = random_track(5, seed=3)
    glossy = 0
    for seed in range(40):
        rng3, rng4 = np.random.default_rng(seed), np.random.default_rng(seed)
        a, b = sample_visuals(v3, rng3, track, Camera()), sample_visuals(v4, rng4, track, Camera())
        assert rng3.bit_generator.state == rng4.bit_generator.state  # no draw shifted
        assert a == replace(b, style=replace(b.style, gloss=None))
        assert b == sample_visuals(v4, np.random.default_rng(seed), track, Camera())
        gloss = b.style.gloss
        if gloss is not None:
            glossy += 1
            assert b.style.hall is not None
            lo, hi = v4.hall.floor_reflectivity
            assert lo <= gloss.reflectivity <= hi
            assert v4.hall.floor_blur_px[0] <= gloss.blur_px <= v4.hall.floor_blur_px[1]
    assert 3 <= glossy <= 20


def test_v4_frames_are_v3_frames_with_reflections_on_the_floor():
    def frames(name):
        recipe = load_recipe(name)
        recipe = replace(recipe, dataset=replace(recipe.dataset, width=160, height=120,
                                                 frames_per_scene=2))  # fmt: skip
        return list(iter_samples(recipe, 7, ShardSpec("train-0000", "train", 0, 1, 40)))

    reflected = 0
    for a, b in zip(frames("gates-v3"), frames("gates-v4"), strict=True):
        np.testing.assert_array_equal(a.frame.seg, b.frame.seg)
        np.testing.assert_array_equal(a.frame.depth, b.frame.depth)
        assert [lab.corners_px.tolist() for lab in a.labels] == [
            lab.corners_px.tolist() for lab in b.labels
        ]
        changed = (a.frame.rgb != b.frame.rgb).any(axis=2)
        # on the floor, or next to it where a lens interpolates the floor's colour in
        near_floor = cv2.dilate((a.frame.seg == GROUND_ID).astype(np.uint8), np.ones((5, 5)))
        assert near_floor[changed].all()
        if not a.camera.distorted:
            assert (a.frame.seg[changed] == GROUND_ID).all()
        reflected += changed.any()
        if not changed.any():
            np.testing.assert_array_equal(a.rgb, b.rgb)
    assert reflected >= 3


def test_the_packaged_v4_recipe_is_the_one_in_datasets():
    assert load_recipe(ROOT / "datasets" / "gates-v4.toml") == load_recipe("gates-v4")
