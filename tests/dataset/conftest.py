"""Tiny datasets for the gen-dataset tests: 160x120 images, shards of 4, generated once per session."""

from __future__ import annotations

from pathlib import Path

import pytest

from icarus_vision.dataset import generate_dataset

RECIPE = Path(__file__).resolve().parents[2] / "datasets" / "gates-v1.toml"
TINY_IMAGES = 16
"""Images of the reference dataset: train 8 (2 shards), val 4 (1 shard), test 4 (1 shard)."""


def write_recipe(path: Path, name: str = "gates-v1", **dataset) -> Path:
    """gates-v1 with a small ``[dataset]`` section (160x120, shards of 4, 3 frames per scene)."""
    settings = {"width": 160, "height": 120, "splits": "[0.5, 0.25, 0.25]", "shard_size": 4}
    settings.update({"frames_per_scene": 3, **dataset})
    text = RECIPE.read_text().split("[dataset]")[0].replace('name = "gates-v1"', f'name = "{name}"')
    text += "[dataset]\n" + "".join(f"{k} = {v}\n" for k, v in settings.items())
    path.write_text(text)
    return path


def files_of(folder: Path) -> dict[str, bytes]:
    """Every file under ``folder`` (relative path -> bytes)."""
    return {
        str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()
    }


@pytest.fixture(scope="session")
def tiny_recipe(tmp_path_factory) -> Path:
    return write_recipe(tmp_path_factory.mktemp("recipe") / "tiny.toml")


@pytest.fixture(scope="session")
def reference(tiny_recipe, tmp_path_factory):
    """A complete tiny dataset made by 2 worker processes: (folder, GenerationResult)."""
    out = tmp_path_factory.mktemp("reference") / "ds"
    result = generate_dataset(tiny_recipe, out, TINY_IMAGES, workers=2, seed=3)
    return out, result
