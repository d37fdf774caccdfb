"""Visual domain-randomisation recipe: frozen dataclasses of ranges, loaded from TOML.

A recipe file (e.g. ``datasets/gates-v1.toml``) has one table per dataclass below: ``[gates]``,
``[ground]``, ``[sky]``, ``[light]``, ``[distractors]``, ``[camera]``, ``[sensor]``, plus a top-level
``name``. Missing keys take the defaults; an unknown key or a bad value raises ValueError naming the
key and the file. Ranges are ``[low, high]`` and are sampled uniformly.
"""

from __future__ import annotations

import math
import os
import tomllib
import typing
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path

from icarus_vision.render.textures import KINDS

Range = tuple[float, float]


@dataclass(frozen=True)
class SurfaceRanges:
    """Look of a surface: pattern kind, two colours in HSV, texture scale."""

    kinds: tuple[str, ...] = KINDS
    """Patterns to draw from: ``solid``, ``stripes``, ``checker``, ``noise``."""
    kind_weights: tuple[float, ...] = (0.4, 0.2, 0.2, 0.2)
    """Relative weight of each entry of ``kinds``."""
    hue: Range = (0.0, 1.0)
    """Hue of the main colour, in [0, 1] (wraps)."""
    saturation: Range = (0.0, 1.0)
    """Saturation of the main colour."""
    value: Range = (0.2, 1.0)
    """Value (brightness) of the main colour."""
    contrast: Range = (0.1, 0.6)
    """Value difference between the second and the main colour (second is darker or lighter)."""
    tile: Range = (0.2, 2.0)
    """Texture tile size: metres on gates and ground, pixels on the sky."""


@dataclass(frozen=True)
class GateRanges(SurfaceRanges):
    """Gate look. Colours come from ``palette`` (jittered) or, with ``random_color_prob``, from the
    HSV ranges inherited from :class:`SurfaceRanges`."""

    kind_weights: tuple[float, ...] = (0.55, 0.2, 0.15, 0.1)
    """Relative weight of each entry of ``kinds``."""
    palette: tuple[tuple[float, float, float], ...] = ((1.0, 0.35, 0.0),)
    """Typical race-gate RGB colours in [0, 1]."""
    palette_jitter: float = 0.08
    """Uniform jitter added to each RGB channel of a palette colour."""
    random_color_prob: float = 0.25
    """Probability of an HSV-random colour instead of a palette one."""
    same_look_prob: float = 0.7
    """Probability that all gates of a frame share one look (else one look per gate)."""
    tile: Range = (0.1, 0.5)
    """Texture tile size on the bars, m."""
    frame_width: Range = (0.06, 0.16)
    """Rendered bar width, m."""


@dataclass(frozen=True)
class LightRanges:
    """The directional light."""

    elevation_deg: Range = (20.0, 90.0)
    """Light elevation above the horizon, degrees."""
    azimuth_deg: Range = (0.0, 360.0)
    """Light azimuth about world z, degrees."""
    ambient: Range = (0.35, 0.8)
    """Ambient coefficient."""
    diffuse: Range = (0.1, 0.6)
    """Diffuse coefficient."""
    specular: Range = (0.0, 0.3)
    """Specular coefficient."""
    color_jitter: float = 0.1
    """Each RGB channel of the white light is scaled by 1 - U(0, color_jitter)."""
    shadow_prob: float = 0.3
    """Probability of rendering shadows (objects on objects; the ground is shaded but unshadowed)."""


@dataclass(frozen=True)
class DistractorRanges:
    """Non-gate objects around the gates."""

    count: tuple[int, int] = (0, 8)
    """Number of distractors per scene, inclusive range."""
    gate_like_prob: float = 0.3
    """Probability that a distractor is gate-like: an arch or a non-square frame in gate colours."""
    distance: Range = (1.5, 12.0)
    """Horizontal distance from a randomly chosen gate's centre, m."""
    size: Range = (0.2, 2.0)
    """Typical extent, m."""
    height: Range = (0.0, 3.0)
    """Height of the object's centre above the ground, m (raised so it never sinks)."""


@dataclass(frozen=True)
class CameraJitter:
    """Camera parameters around the quadrotor's nominal camera."""

    hfov_deg: Range = (80.0, 110.0)
    """Horizontal field of view, degrees."""
    uptilt_deg: Range = (10.0, 35.0)
    """Camera uptilt, degrees."""
    roll_deg: Range = (-3.0, 3.0)
    """Mount roll about the optical axis, degrees."""


@dataclass(frozen=True)
class SensorRanges:
    """Image degradations applied after rendering."""

    noise_std: Range = (0.0, 6.0)
    """Standard deviation of additive Gaussian noise, 8-bit levels."""
    gamma: Range = (0.8, 1.25)
    """Gamma applied to the whole image."""
    gain: Range = (0.85, 1.15)
    """Brightness gain."""
    blur_prob: float = 0.2
    """Probability of a Gaussian blur."""
    blur_sigma_px: Range = (0.4, 1.2)
    """Blur standard deviation, pixels."""


@dataclass(frozen=True)
class Recipe:
    """A visual domain-randomisation recipe (one per dataset)."""

    name: str = "default"
    """Short identifier, recorded in the dataset manifest."""
    gates: GateRanges = field(default_factory=GateRanges)
    """Gate colour, texture and frame width."""
    ground: SurfaceRanges = field(default_factory=SurfaceRanges)
    """Ground colour and texture (``tile`` in metres)."""
    sky: SurfaceRanges = field(default_factory=lambda: SurfaceRanges(tile=(8.0, 80.0)))
    """Background colour and texture (``tile`` in pixels)."""
    light: LightRanges = field(default_factory=LightRanges)
    """Light direction, strengths and shadows."""
    distractors: DistractorRanges = field(default_factory=DistractorRanges)
    """Distractor objects."""
    camera: CameraJitter = field(default_factory=CameraJitter)
    """Camera FOV, uptilt and roll jitter."""
    sensor: SensorRanges = field(default_factory=SensorRanges)
    """Sensor noise."""

    def to_dict(self) -> dict:
        """Plain nested dict (JSON-ready) of the resolved recipe."""
        return asdict(self)


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
    if isinstance(obj, CameraJitter) and not (0 < obj.hfov_deg[0] and obj.hfov_deg[1] < 170):
        raise _fail(source, f"{prefix}hfov_deg", f"must lie in (0, 170), got {list(obj.hfov_deg)}")


def recipe_from_dict(data: dict, source: str = "<memory>") -> Recipe:
    """Build and validate a Recipe from a parsed TOML table."""
    return _build(Recipe, data, "", source)


def load_recipe(path: str | os.PathLike) -> Recipe:
    """Load a recipe TOML file; ValueError names the file and the key on any problem."""
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"{path}: recipe file not found")
    try:
        data = tomllib.loads(path.read_text())
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as e:
        raise ValueError(f"{path}: not a valid TOML file ({e})") from None
    return recipe_from_dict(data, source=str(path))
