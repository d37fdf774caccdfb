from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from icarus_vision.render.camera import Camera
from icarus_vision.render.randomize import (
    Recipe,
    SensorNoise,
    apply_sensor_noise,
    load_recipe,
    recipe_from_dict,
    sample_visuals,
)
from icarus_vision.render.recipe import GateRanges
from icarus_vision.sim.random_track import random_track

RECIPE = Path(__file__).resolve().parents[2] / "datasets" / "gates-v1.toml"


def test_shipped_recipe_loads_and_round_trips():
    recipe = load_recipe(RECIPE)
    assert recipe.name == "gates-v1"
    assert len(recipe.gates.palette) >= 4
    assert recipe_from_dict(recipe.to_dict(), "again") == recipe


def test_every_field_has_a_default():
    for cls in (Recipe, GateRanges):
        for f in dataclasses.fields(cls):
            assert (
                f.default is not dataclasses.MISSING or f.default_factory is not dataclasses.MISSING
            )


@pytest.mark.parametrize(
    "text, key",
    [
        ('name = "x"\nbogus = 1\n', "bogus"),
        ("[gates]\ncolour = [1, 0, 0]\n", "gates.colour"),
        ("[light]\nambient = [0.9, 0.1]\n", "light.ambient"),
        ("[light]\nshadow_prob = 1.5\n", "light.shadow_prob"),
        ('[ground]\nkinds = ["solid", "plaid"]\nkind_weights = [1, 1]\n', "ground.kinds"),
        ("[gates]\nkind_weights = [1.0]\n", "gates.kind_weights"),
        ('[camera]\nhfov_deg = ["wide", 90]\n', "camera.hfov_deg"),
        ("[distractors]\ncount = [0.5, 3]\n", "distractors.count"),
        ("sky = 3\n", "sky"),
        ("[sensor\n", "not a valid TOML"),
    ],
)
def test_bad_recipe_errors_name_key_and_file(tmp_path, text, key):
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(ValueError) as err:
        load_recipe(path)
    assert key in str(err.value) and str(path) in str(err.value)


def test_missing_recipe_file(tmp_path):
    with pytest.raises(ValueError, match="not found"):
        load_recipe(tmp_path / "nope.toml")


def test_sampling_is_deterministic_and_within_ranges():
    recipe = load_recipe(RECIPE)
    track = random_track(5, seed=0)
    draws = [sample_visuals(recipe, np.random.default_rng(11), track, Camera()) for _ in range(2)]
    assert draws[0] == draws[1]
    rng = np.random.default_rng(0)
    for _ in range(30):
        v = sample_visuals(recipe, rng, track)
        lo, hi = recipe.camera.hfov_deg
        assert lo <= v.camera.hfov_deg <= hi and (v.camera.width, v.camera.height) == (320, 240)
        assert recipe.gates.frame_width[0] <= v.style.frame_width <= recipe.gates.frame_width[1]
        lo, hi = recipe.distractors.count
        assert lo <= len(v.distractors) <= hi
        for d in v.distractors:
            if d.shape == "frame":
                assert abs(d.size[0] - d.size[1]) > 0.2 * max(d.size[:2])  # never gate-square


def test_sensor_noise():
    img = np.full((24, 32, 3), 100, np.uint8)
    assert np.array_equal(apply_sensor_noise(img, SensorNoise(), np.random.default_rng(0)), img)
    noisy = apply_sensor_noise(img, SensorNoise(4.0, 1.0, 1.2, 1.0), np.random.default_rng(0))
    assert noisy.dtype == np.uint8 and noisy.shape == img.shape
    assert 110 < noisy.mean() < 130 and noisy.std() > 2
    again = apply_sensor_noise(img, SensorNoise(4.0, 1.0, 1.2, 1.0), np.random.default_rng(0))
    assert np.array_equal(noisy, again)
