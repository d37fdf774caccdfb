"""The gates-v5 recipe: screens (filled rectangles in a bezel, square or not) among the
distractors; drawn in range and seeded, never in the older recipes, rendered and never labelled."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from icarus_vision.render.camera import Camera
from icarus_vision.render.labels import frame_labels
from icarus_vision.render.randomize import load_recipe, sample_visuals
from icarus_vision.render.scene import Scene
from icarus_vision.render.style import Distractor, SceneStyle
from icarus_vision.render.textures import Material
from icarus_vision.sim.random_track import random_track
from icarus_vision.sim.track import Gate, Track

ROOT = Path(__file__).resolve().parents[2]
LEVEL = np.array([0.0, 0.0, 0.0, 1.0])
EYE = np.array([0.0, 0.0, 2.0])


def test_v5_draws_screens_in_range_seeded_and_the_older_recipes_none():
    v5, v4 = load_recipe("gates-v5"), load_recipe("gates-v4")
    assert load_recipe(ROOT / "datasets" / "gates-v5.toml") == v5
    track = random_track(5, seed=3)
    screens, aspects = [], []
    for seed in range(40):
        v = sample_visuals(v5, np.random.default_rng(seed), track, Camera())
        assert v == sample_visuals(v5, np.random.default_rng(seed), track, Camera())
        for d in v.distractors:
            if d.shape == "screen":
                w, h, bezel = d.size
                assert 0.4 <= w <= 2.5 and 0.55 * w <= h <= 1.8 * w and 0 < bezel < 0.13 * w
                assert d.pos[2] >= h / 2 + bezel and d.material2 is not None
                screens.append(d)
                aspects.append(h / w)
        old = sample_visuals(v4, np.random.default_rng(seed), track, Camera())
        assert all(d.shape != "screen" for d in old.distractors)
    assert len(screens) >= 10
    assert min(abs(a - 1.0) for a in aspects) < 0.1  # squares too: not only non-square frames


def test_a_screen_renders_filled_and_is_never_labelled():
    track = Track("one", (Gate((6.0, 2.5, 2.0)),), start_pos=(0.0, 0.0, 0.2))
    style = SceneStyle(gate_materials=(Material("solid", (1.0, 0.4, 0.0)),), frame_width=0.1)
    bezel, panel = Material("solid", (0.05, 0.05, 0.05)), Material("solid", (0.1, 0.2, 0.9))
    screen = Distractor("screen", (5.0, -0.8, 2.0), (1.0, 1.0, 0.06), 0.0, bezel, panel)
    with Scene(track, Camera(uptilt_deg=0.0), style, (screen,)) as scene:
        frame = scene.render(EYE, LEVEL)
        labels = frame_labels(scene, frame, EYE, LEVEL)
    gate_body = scene.gate_bodies[0]
    assert [lab.gate_id for lab in labels] == [0]  # the gate only
    others = frame.seg[(frame.seg >= 0) & (frame.seg != gate_body)]
    assert others.size > 500  # the screen shows
    ys, xs = np.nonzero((frame.seg >= 0) & (frame.seg != gate_body))
    centre = frame.rgb[int(ys.mean()), int(xs.mean())].astype(int)
    assert centre[2] > centre[0] + 40  # its middle is the blue panel, not background seen through
