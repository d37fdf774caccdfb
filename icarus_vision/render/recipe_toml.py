"""Loading and validation of recipe TOML files into the dataclasses of
:mod:`icarus_vision.render.recipe_sections`.

Missing keys take the defaults; an unknown key or a bad value raises ValueError naming the key and
the file.
"""

from __future__ import annotations

import os
import typing
from dataclasses import fields, is_dataclass
from pathlib import Path

from icarus_vision.fileio import read_toml
from icarus_vision.render.recipe_sections import (
    EXTRA_SHAPES,
    CameraJitter,
    DatasetSettings,
    DistractorRanges,
    GateRanges,
    HallRanges,
    PoseRanges,
    Recipe,
    SensorRanges,
    SurfaceRanges,
    TrackRanges,
)
from icarus_vision.render.textures import ALL_KINDS
from icarus_vision.validation import check_table


def _fail(source: str, key: str, msg: str) -> ValueError:
    return ValueError(f"{source}: {key}: {msg}")


def _build(cls, table, prefix: str, source: str):
    if not isinstance(table, dict):
        raise _fail(source, prefix.rstrip(".") or "<top>", "must be a table")
    kwargs = check_table(cls, table, source, ValueError, prefix)
    hints = typing.get_type_hints(cls)
    for name, value in kwargs.items():
        if is_dataclass(hints[name]):
            kwargs[name] = _build(hints[name], value, f"{prefix}{name}.", source)
    obj = cls(**kwargs)
    _validate(obj, prefix, source)
    return obj


def _validate(obj, prefix: str, source: str) -> None:
    """Range and probability checks of one section."""
    for f in fields(obj):
        v, key = getattr(obj, f.name), f"{prefix}{f.name}"
        if f.name.endswith("_prob") and not 0.0 <= v <= 1.0:
            raise _fail(source, key, f"must be a probability in [0, 1], got {v}")
        if isinstance(v, tuple) and len(v) == 2 and all(isinstance(x, int | float) for x in v):
            if v[0] > v[1]:
                raise _fail(source, key, f"range low must be <= high, got {list(v)}")
            if f.name in ("hue", "saturation", "value", "contrast") and not (
                0 <= v[0] and v[1] <= 1
            ):
                raise _fail(source, key, f"must lie in [0, 1], got {list(v)}")
            if f.name in ("count", "tile", "size", "frame_width", "noise_std", "gamma", "gain",
                          "hfov_deg", "blur_sigma_px", "ambient", "diffuse", "specular", "distance",
                          "depth", "trim_width", "motion_blur_px", "defocus_px", "bloom",
                          "vignette", "margin", "lights", "banners", "height",
                          "floor_blur_px") \
                    and v[0] < 0:  # fmt: skip
                raise _fail(source, key, f"must be >= 0, got {list(v)}")
    if isinstance(obj, SurfaceRanges):
        bad = [k for k in obj.kinds if k not in ALL_KINDS]
        if bad:
            raise _fail(
                source, f"{prefix}kinds", f"unknown kind(s) {bad}; allowed: {list(ALL_KINDS)}"
            )
        w = obj.kind_weights
        if len(w) != len(obj.kinds) or any(x < 0 for x in w) or sum(w) <= 0:
            raise _fail(
                source, f"{prefix}kind_weights", "needs one weight >= 0 per kind, not all 0"
            )
    if isinstance(obj, GateRanges):
        for c in obj.palette:
            if not all(0.0 <= x <= 1.0 for x in c):
                raise _fail(
                    source, f"{prefix}palette", f"RGB values must lie in [0, 1], got {list(c)}"
                )
        if obj.tile[0] <= 0 or obj.frame_width[0] <= 0:
            raise _fail(source, f"{prefix}tile/frame_width", "must be > 0")
    _validate_later(obj, prefix, source)
    _validate_geometry(obj, prefix, source)
    if isinstance(obj, CameraJitter) and not (0 < obj.hfov_deg[0] and obj.hfov_deg[1] < 170):
        raise _fail(source, f"{prefix}hfov_deg", f"must lie in (0, 170), got {list(obj.hfov_deg)}")


def _validate_later(obj, prefix: str, source: str) -> None:
    """Checks of the keys added with the gates-v3 and gates-v4 recipes."""
    if isinstance(obj, GateRanges):
        for c in obj.trim_palette:
            if len(c) != 3 or not all(0.0 <= x <= 1.0 for x in c):
                raise _fail(
                    source, f"{prefix}trim_palette", f"RGB values must lie in [0, 1], got {list(c)}"
                )
        if obj.trim_prob > 0 and obj.trim_width[0] <= 0:
            raise _fail(source, f"{prefix}trim_width", "must be > 0")
    if isinstance(obj, DistractorRanges):
        bad = [x for x in obj.extra_shapes if x not in EXTRA_SHAPES]
        if bad or (obj.extra_prob > 0 and not obj.extra_shapes):
            raise _fail(source, f"{prefix}extra_shapes",
                        f"must be some of {', '.join(EXTRA_SHAPES)}, got {list(obj.extra_shapes)}")  # fmt: skip
    if isinstance(obj, CameraJitter):
        if not obj.aspects or any(not 0.2 <= a <= 5.0 for a in obj.aspects):
            raise _fail(
                source, f"{prefix}aspects", f"need ratios in [0.2, 5], got {list(obj.aspects)}"
            )
    if isinstance(obj, SensorRanges):
        if not (1 <= obj.jpeg_quality[0] and obj.jpeg_quality[1] <= 100):
            raise _fail(source, f"{prefix}jpeg_quality", "must lie in [1, 100]")
        if obj.vignette[1] > 1.0 or obj.color_cast < 0:
            raise _fail(source, f"{prefix}vignette/color_cast", "vignette <= 1, color_cast >= 0")
    if isinstance(obj, HallRanges):
        if obj.height[0] <= 2.0:
            raise _fail(source, f"{prefix}height", "the ceiling must be higher than 2 m")
        if not (0.0 <= obj.floor_reflectivity[0] and obj.floor_reflectivity[1] <= 1.0):
            raise _fail(source, f"{prefix}floor_reflectivity",
                        f"must lie in [0, 1], got {list(obj.floor_reflectivity)}")  # fmt: skip


def _validate_geometry(obj, prefix: str, source: str) -> None:
    """Checks of the ``[tracks]``, ``[poses]`` and ``[dataset]`` sections."""
    if isinstance(obj, TrackRanges):
        if obj.gates[0] < 1:
            raise _fail(source, f"{prefix}gates", f"must be >= 1, got {list(obj.gates)}")
        if obj.spacing[0] < 3.0:
            raise _fail(source, f"{prefix}spacing", "must be >= 3 m (gates stay 3 m apart)")
        if obj.size[0] <= 0:
            raise _fail(source, f"{prefix}size", "must be > 0")
    if isinstance(obj, PoseRanges):
        if obj.distance[0] <= 0 or obj.height[0] <= 0 or obj.lateral_std < 0:
            raise _fail(source, f"{prefix}distance/height/lateral_std", "must be > 0")
        for name in ("roll_deg", "pitch_deg"):
            lo, hi = getattr(obj, name)
            if not (-90.0 < lo and hi < 90.0):
                raise _fail(source, f"{prefix}{name}", "must lie in (-90, 90)")
    if isinstance(obj, DatasetSettings):
        for name in ("width", "height"):
            if not 8 <= getattr(obj, name) <= 4096:
                raise _fail(source, f"{prefix}{name}", "must lie in [8, 4096]")
        for name in ("shard_size", "frames_per_scene"):
            if getattr(obj, name) < 1:
                raise _fail(source, f"{prefix}{name}", "must be >= 1")
        if any(x < 0 for x in obj.splits) or abs(sum(obj.splits) - 1.0) > 1e-6:
            raise _fail(
                source,
                f"{prefix}splits",
                f"need 3 fractions >= 0 summing to 1, got {list(obj.splits)}",
            )


def recipe_from_dict(data: dict, source: str = "<memory>") -> Recipe:
    """Build and validate a Recipe from a parsed TOML table."""
    return _build(Recipe, data, "", source)


PACKAGED = Path(__file__).resolve().parent / "recipes"
"""The recipes that ship with the package (``gates-v1``: the shipped detector's training data;
``gates-v3``: real gates and places; ``gates-v4``: gates-v3 with glossy hall floors);
``datasets/*.toml`` in the repository point at them."""


def packaged_recipes() -> list[str]:
    """Names of the packaged recipes."""
    return sorted(p.stem for p in PACKAGED.glob("*.toml"))


def load_recipe(path: str | os.PathLike) -> Recipe:
    """Load a recipe TOML file, or a packaged recipe by name (``gates-v1``, ``gates-v3``, ...);
    ValueError names the file and the key on any problem."""
    if not Path(path).exists() and (PACKAGED / f"{path}.toml").is_file():
        path = PACKAGED / f"{path}.toml"
    elif not Path(path).exists() and "/" not in str(path) and not str(path).endswith(".toml"):
        raise FileNotFoundError(
            f"{path}: no such recipe file or packaged recipe ({', '.join(packaged_recipes())})"
        )
    data = read_toml(path, "recipe", ValueError)
    return recipe_from_dict(data, source=str(path))
