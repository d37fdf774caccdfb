"""Loading and validation of recipe TOML files into the dataclasses of
:mod:`icarus_vision.render.recipe_sections`.

Missing keys take the defaults; an unknown key or a bad value raises ValueError naming the key and
the file.
"""

from __future__ import annotations

import math
import os
import typing
from dataclasses import fields

from icarus_vision.fileio import read_toml
from icarus_vision.render.recipe_sections import (
    CameraJitter,
    DatasetSettings,
    GateRanges,
    PoseRanges,
    Recipe,
    SurfaceRanges,
    TrackRanges,
)
from icarus_vision.render.textures import KINDS


def _fail(source: str, key: str, msg: str) -> ValueError:
    return ValueError(f"{source}: {key}: {msg}")


def _number(v, key: str, source: str) -> float:
    if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
        raise _fail(source, key, f"must be a finite number, got {v!r}")
    return float(v)


def _convert(tp, v, key: str, source: str):
    """Check and convert one TOML value to the field type ``tp``."""
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    if tp is str:
        if not isinstance(v, str) or not v:
            raise _fail(source, key, f"must be a non-empty string, got {v!r}")
        return v
    if tp is float:
        return _number(v, key, source)
    if tp is int:
        if isinstance(v, bool) or not isinstance(v, int):
            raise _fail(source, key, f"must be an integer, got {v!r}")
        return v
    if origin is tuple:
        if not isinstance(v, list | tuple):
            raise _fail(source, key, f"must be a list, got {v!r}")
        if len(args) == 2 and args[1] is Ellipsis:
            if not v:
                raise _fail(source, key, "must not be empty")
            return tuple(_convert(args[0], x, key, source) for x in v)
        if len(v) != len(args):
            raise _fail(source, key, f"must have {len(args)} values, got {v!r}")
        if args == (int, int):
            if not all(isinstance(x, int) and not isinstance(x, bool) for x in v):
                raise _fail(source, key, f"must be integers, got {v!r}")
            return (int(v[0]), int(v[1]))
        return tuple(_convert(a, x, key, source) for a, x in zip(args, v, strict=True))
    raise TypeError(f"unsupported recipe field type {tp!r}")  # pragma: no cover


def _build(cls, table, prefix: str, source: str):
    if not isinstance(table, dict):
        raise _fail(source, prefix or "<top>", "must be a table")
    hints = typing.get_type_hints(cls)
    known = {f.name: f for f in fields(cls)}
    for key in table:
        if key not in known:
            raise _fail(source, f"{prefix}{key}", f"unknown key; allowed: {sorted(known)}")
    kwargs = {}
    for name, value in table.items():
        tp = hints[name]
        if isinstance(tp, type) and hasattr(tp, "__dataclass_fields__"):
            kwargs[name] = _build(tp, value, f"{prefix}{name}.", source)
        else:
            kwargs[name] = _convert(tp, value, f"{prefix}{name}", source)
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
                          "hfov_deg", "blur_sigma_px", "ambient", "diffuse", "specular", "distance") \
                    and v[0] < 0:  # fmt: skip
                raise _fail(source, key, f"must be >= 0, got {list(v)}")
    if isinstance(obj, SurfaceRanges):
        bad = [k for k in obj.kinds if k not in KINDS]
        if bad:
            raise _fail(source, f"{prefix}kinds", f"unknown kind(s) {bad}; allowed: {list(KINDS)}")
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
    _validate_geometry(obj, prefix, source)
    if isinstance(obj, CameraJitter) and not (0 < obj.hfov_deg[0] and obj.hfov_deg[1] < 170):
        raise _fail(source, f"{prefix}hfov_deg", f"must lie in (0, 170), got {list(obj.hfov_deg)}")


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


def load_recipe(path: str | os.PathLike) -> Recipe:
    """Load a recipe TOML file; ValueError names the file and the key on any problem."""
    data = read_toml(path, "recipe", ValueError)
    return recipe_from_dict(data, source=str(path))
