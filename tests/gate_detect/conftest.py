"""A tiny generated dataset (160x120, 16 images) shared by the detector tests, tiny models, and
a synthetic gate frame."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from icarus_vision.dataset import generate_dataset
from icarus_vision.gate_detect.cnn.model import ModelConfig

RECIPE = Path(__file__).resolve().parents[2] / "datasets" / "gates-v1.toml"
TINY_MODEL = ModelConfig(
    input_size=(80, 60), image_size=(160, 120), widths=(8, 8, 16, 16), head_width=8, stem_width=0
)
"""A very small network for the training tests (half-resolution input, output grid 40x30)."""

QUAD = np.array([[100.0, 60.0], [190.0, 70.0], [185.0, 160.0], [95.0, 150.0]])
"""A candidate gate's opening in a 320x240 frame, pixels, TL, TR, BR, BL."""


def gate_image() -> np.ndarray:
    """A 320x240 RGB frame: an orange gate on grey whose opening is QUAD."""
    img = np.full((240, 320, 3), 110, np.uint8)
    centre = QUAD.mean(axis=0)
    outer = centre + 1.3 * (QUAD - centre)
    cv2.fillPoly(img, [np.round(outer).astype(np.int32)], (255, 90, 0))
    cv2.fillPoly(img, [np.round(QUAD).astype(np.int32)], (110, 110, 110))
    return img


def write_recipe(path: Path) -> Path:
    """gates-v1 with 160x120 images, shards of 4, 2 frames per scene, splits 50/25/25."""
    text = RECIPE.read_text().split("[dataset]")[0]
    text += (
        "[dataset]\nwidth = 160\nheight = 120\nsplits = [0.5, 0.25, 0.25]\n"
        "shard_size = 4\nframes_per_scene = 2\n"
    )
    path.write_text(text)
    return path


@pytest.fixture(scope="session")
def tiny_dataset(tmp_path_factory) -> Path:
    """16 images: train 8, val 4, test 4 (seed 5)."""
    root = tmp_path_factory.mktemp("detector-data")
    recipe = write_recipe(root / "tiny.toml")
    out = root / "ds"
    generate_dataset(recipe, out, 16, workers=1, seed=5)
    return out


@pytest.fixture(autouse=True)
def one_torch_thread():
    """Tiny networks on a shared machine: more threads only contend (and can be 100x slower)."""
    import torch

    n = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(n)


def facing_box(w: float, h: float, cx: float, cy: float = 120.0) -> np.ndarray:
    """(4, 2) corners TL, TR, BR, BL of a w x h px opening centred at (cx, cy), facing the camera."""
    return np.array([[cx - w / 2, cy - h / 2], [cx + w / 2, cy - h / 2],
                     [cx + w / 2, cy + h / 2], [cx - w / 2, cy + h / 2]])  # fmt: skip
