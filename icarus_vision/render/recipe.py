"""Visual domain-randomisation recipe: frozen dataclasses of ranges, loaded from TOML.

A recipe file (e.g. ``datasets/gates-v1.toml``) has one table per dataclass below: ``[gates]``,
``[ground]``, ``[sky]``, ``[light]``, ``[distractors]``, ``[camera]``, ``[sensor]``, the geometry
of the frames (``[tracks]``, ``[poses]``), the dataset layout (``[dataset]``), plus a top-level
``name``. Missing keys take the defaults; an unknown key or a bad value raises ValueError naming the
key and the file. Ranges are ``[low, high]`` and are sampled uniformly.
"""

from __future__ import annotations

import math
import os
import typing
from dataclasses import asdict, dataclass, field, fields

from icarus_vision.fileio import read_toml
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
    """Probability of rendering shadows: objects on objects (TinyRenderer's shadow map) and on the
    ground (:mod:`icarus_vision.render.shadows`)."""


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
class TrackRanges:
    """Random track layouts (:func:`icarus_vision.sim.random_track.random_track`); one per scene."""

    gates: tuple[int, int] = (3, 10)
    """Number of gates per track, inclusive range."""
    spacing: Range = (4.0, 8.0)
    """Distance between consecutive gates, m."""
    max_turn_deg: float = 60.0
    """Largest change of direction from one gate to the next, degrees."""
    height: Range = (1.0, 3.0)
    """Height of the gate centres above the ground, m."""
    size: Range = (1.0, 1.0)
    """Side of the square inner opening, m (one draw per track)."""


@dataclass(frozen=True)
class PoseRanges:
    """Racing-like camera poses: the drone on its way to a gate (:mod:`icarus_vision.render.poses`)."""

    distance: Range = (0.5, 15.0)
    """Distance from the camera to the centre of the gate it approaches, m (drawn uniformly)."""
    racing_line_prob: float = 0.5
    """Probability of a pose on the straight line from the previous gate (or the start) to the
    target gate, offset by ``lateral_std``; otherwise the pose lies in the approach cone below."""
    lateral_std: float = 0.5
    """Standard deviation of the sideways and vertical offsets from the racing line, m."""
    approach_azimuth_deg: Range = (-50.0, 50.0)
    """Approach cone: horizontal angle between the gate's passage axis and the camera's bearing
    from the gate (on the approach side), degrees."""
    approach_elevation_deg: Range = (-10.0, 30.0)
    """Approach cone: elevation of the camera seen from the gate's centre, degrees."""
    aim_offset_deg: Range = (0.0, 40.0)
    """Angle between the direction the camera is aimed at and the gate's centre, degrees; large
    values put the gate at or across the image border."""
    roll_deg: Range = (-45.0, 45.0)
    """Body roll, degrees."""
    pitch_deg: Range = (-45.0, 45.0)
    """Body pitch limits (positive: nose down), degrees; the pitch that aims the camera is clipped
    to them."""
    height: Range = (0.3, 6.0)
    """Allowed camera height above the ground, m; positions are clamped into it."""
    no_gate_prob: float = 0.1
    """Share of frames drawn to show no gate at all (the camera looks away from every gate)."""


@dataclass(frozen=True)
class DatasetSettings:
    """Layout of a generated dataset (``icarus-vision gen-dataset``)."""

    width: int = 320
    """Image width, pixels."""
    height: int = 240
    """Image height, pixels."""
    splits: tuple[float, float, float] = (0.8, 0.1, 0.1)
    """Fractions of the images in the ``train``, ``val`` and ``test`` splits (sum 1)."""
    shard_size: int = 100
    """Images per shard, the unit of parallel work, checksums and resuming."""
    frames_per_scene: int = 20
    """Frames rendered from one scene (one random track, look and camera) before the next."""


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
    tracks: TrackRanges = field(default_factory=TrackRanges)
    """Random track layouts."""
    poses: PoseRanges = field(default_factory=PoseRanges)
    """Camera poses."""
    dataset: DatasetSettings = field(default_factory=DatasetSettings)
    """Resolution, splits and sharding of a generated dataset."""

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
