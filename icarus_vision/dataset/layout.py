"""Where things live in a dataset folder, and how the images are cut into splits and shards.

A dataset folder::

    config.json             what is being generated (recipe, seed, num_images, version); written first
    images/000001.png ...   the images, ids 1..N: train first, then val, then test
    shards/<split>-<k>.json one record per shard: its images' labels and checksums; written last
    annotations/{train,val,test}.json  COCO keypoints, one file per split
    contact_sheet.png       a grid of samples with their labelled corners drawn
    manifest.json           written last of all: a folder without it is incomplete

Images are numbered in split order and every shard holds consecutive images of one split, so a
shard is the unit of parallel work, of checksums and of resuming. Each shard draws from its own
random stream, keyed by (seed, split, shard index): its images do not depend on the number of
workers, on which worker renders it, or on timing.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from icarus_vision.render.recipe import DatasetSettings

SPLITS = ("train", "val", "test")
"""Split names, in image-id order."""
CONFIG = "config.json"
MANIFEST = "manifest.json"
CONTACT_SHEET = "contact_sheet.png"
IMAGES = "images"
SHARDS = "shards"
ANNOTATIONS = "annotations"
OWN_DIRS = (IMAGES, SHARDS, ANNOTATIONS)
"""Folders of a dataset folder (removed by ``force``)."""
OWN_FILES = (CONFIG, MANIFEST, CONTACT_SHEET)
"""Files of a dataset folder (removed by ``force``)."""


@dataclass(frozen=True)
class ShardSpec:
    """One shard: ``count`` consecutive images of one split.

    Attributes:
        name: ``<split>-<index:04d>``, e.g. ``train-0003``.
        split: ``train``, ``val`` or ``test``.
        index: index of the shard within its split.
        first_id: image id of its first image (ids start at 1).
        count: number of images.
    """

    name: str
    split: str
    index: int
    first_id: int
    count: int

    @property
    def image_ids(self) -> range:
        """Ids of the shard's images."""
        return range(self.first_id, self.first_id + self.count)

    def rng(self, seed: int) -> np.random.Generator:
        """The shard's own random stream (a function of the seed, split and index only)."""
        key = (SPLITS.index(self.split), self.index)
        return np.random.default_rng(np.random.SeedSequence(seed, spawn_key=key))


def split_counts(num_images: int, fractions: tuple[float, float, float]) -> dict[str, int]:
    """Images per split: val and test rounded from their fractions, train the rest."""
    val = int(round(num_images * fractions[1]))
    test = min(int(round(num_images * fractions[2])), num_images - val)
    return {"train": num_images - val - test, "val": val, "test": test}


def plan_shards(num_images: int, settings: DatasetSettings) -> list[ShardSpec]:
    """Every shard of a dataset of ``num_images`` images, in image-id order."""
    counts = split_counts(num_images, settings.splits)
    specs, first = [], 1
    for split in SPLITS:
        n = counts[split]
        for k, start in enumerate(range(0, n, settings.shard_size)):
            count = min(settings.shard_size, n - start)
            specs.append(ShardSpec(f"{split}-{k:04d}", split, k, first, count))
            first += count
    return specs


def image_file_name(image_id: int) -> str:
    """File name of an image under ``images/``."""
    return f"{image_id:06d}.png"


def shard_path(out_dir: Path, spec: ShardSpec) -> Path:
    """Path of a shard's record."""
    return Path(out_dir) / SHARDS / f"{spec.name}.json"


def split_share(ref: str) -> tuple[str, float | None]:
    """``NAME:SHARE`` -> (NAME, SHARE); a reference that does not end in ``:`` and a number is a
    name alone -> (ref, None)."""
    head, sep, tail = ref.rpartition(":")
    if sep:
        try:
            return head, float(tail)
        except ValueError:
            pass
    return ref, None
