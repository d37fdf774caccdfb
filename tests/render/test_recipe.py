"""The recipe's geometry and dataset sections: [tracks], [poses], [dataset]."""

from __future__ import annotations

from pathlib import Path

import pytest

from icarus_vision.render.recipe import DatasetSettings, PoseRanges, load_recipe, recipe_from_dict

RECIPE = Path(__file__).resolve().parents[2] / "datasets" / "gates-v1.toml"


def test_shipped_recipe_sets_poses_and_dataset():
    r = load_recipe(RECIPE)
    assert r.poses.distance == (0.5, 15.0)
    assert r.poses.roll_deg == (-45.0, 45.0) and r.poses.pitch_deg == (-45.0, 45.0)
    assert 0 < r.poses.no_gate_prob < 0.5
    assert r.dataset == DatasetSettings()
    assert r.tracks.gates[0] >= 1


def test_sections_default_when_missing():
    r = recipe_from_dict({"name": "x"})
    assert r.poses == PoseRanges() and r.dataset == DatasetSettings()


@pytest.mark.parametrize(
    ("data", "key"),
    [
        ({"poses": {"distanse": [1.0, 2.0]}}, "poses.distanse: unknown key"),
        ({"poses": {"distance": [5.0, 1.0]}}, "poses.distance: range low must be <= high"),
        ({"poses": {"roll_deg": [-95.0, 45.0]}}, "poses.roll_deg"),
        ({"poses": {"no_gate_prob": 1.5}}, "poses.no_gate_prob: must be a probability"),
        ({"dataset": {"shard_size": 0}}, "dataset.shard_size: must be >= 1"),
        ({"dataset": {"shard_size": 2.5}}, "dataset.shard_size: must be an integer"),
        ({"dataset": {"width": True}}, "dataset.width: must be an integer"),
        ({"dataset": {"splits": [0.5, 0.5, 0.5]}}, "dataset.splits"),
        ({"dataset": {"splits": [0.5, 0.5]}}, "dataset.splits: must have 3 values"),
        ({"tracks": {"gates": [0, 3]}}, "tracks.gates: must be >= 1"),
        ({"tracks": {"spacing": [1.0, 3.0]}}, "tracks.spacing"),
    ],
)
def test_bad_sections_name_the_key(data, key):
    with pytest.raises(ValueError, match=f"^src: {key}"):
        recipe_from_dict(data, "src")
