"""The output folder's identity: what it holds, refusing to mix datasets, cleaning up after Ctrl-C."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

from icarus_vision.dataset.layout import CONFIG, MANIFEST, OWN_DIRS, OWN_FILES
from icarus_vision.fileio import atomic_write_json


def _describe_difference(old: dict, new: dict) -> str:
    parts = []
    old_recipe, new_recipe = old.get("recipe"), new.get("recipe")
    if old_recipe != new_recipe:
        name = old_recipe.get("name", "?") if isinstance(old_recipe, dict) else "?"
        same = name == new_recipe.get("name")
        parts.append(f"recipe {name!r}" + (" with other settings" if same else ""))
    for key in ("seed", "num_images", "version", "format"):
        if old.get(key) != new.get(key):
            parts.append(f"{key} {old.get(key)!r}")
    if old.get("renderer", "tiny") != new.get("renderer", "tiny"):  # absent: TinyRenderer
        parts.append(f"renderer {old.get('renderer', 'tiny')!r}")
    return ", ".join(parts) or "other settings"


def clear_dataset(out_dir: Path) -> None:
    """Remove a dataset's own files and folders from ``out_dir`` (nothing else)."""
    for name in OWN_DIRS:
        shutil.rmtree(out_dir / name, ignore_errors=True)
    for name in OWN_FILES:
        (out_dir / name).unlink(missing_ok=True)


def remove_temp_files(out_dir: Path) -> None:
    """Delete the temporary files an interrupted atomic write may have left."""
    for folder in (out_dir, *(out_dir / d for d in OWN_DIRS)):
        if folder.is_dir():
            for tmp in folder.glob(".*.tmp"):
                tmp.unlink(missing_ok=True)


def prepare_folder(out_dir: Path, identity: dict, force: bool) -> None:
    """Make ``out_dir`` ready to hold the dataset described by ``identity``.

    A folder that already holds this dataset (same ``config.json``) is kept, to be resumed. A folder
    holding another dataset, or any other non-empty folder, is refused unless ``force``, which
    removes the old dataset's files first.

    Raises:
        ValueError: the folder holds something else and ``force`` is False.
    """
    out_dir = Path(out_dir)
    if out_dir.exists() and not out_dir.is_dir():
        raise ValueError(f"{out_dir}: exists and is not a folder")
    cfg = out_dir / CONFIG
    if cfg.is_file():
        try:
            old = json.loads(cfg.read_text())
        except (OSError, ValueError):
            old = {"format": "<unreadable config.json>"}
        if old != identity:
            if not force:
                raise ValueError(
                    f"{out_dir} holds a different dataset ({_describe_difference(old, identity)}); "
                    "pass --force to overwrite it"
                )
            clear_dataset(out_dir)
    elif out_dir.is_dir() and any(out_dir.iterdir()):
        if not force:
            raise ValueError(
                f"{out_dir} is not empty and holds no gen-dataset output; "
                "choose an empty folder or pass --force to write into it"
            )
        clear_dataset(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    remove_temp_files(out_dir)
    if not cfg.is_file():
        atomic_write_json(cfg, identity)


def mark_incomplete(out_dir: Path) -> None:
    """Remove the manifest: until it is written again, the folder reads as incomplete."""
    (Path(out_dir) / MANIFEST).unlink(missing_ok=True)
