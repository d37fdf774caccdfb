"""Quadrotor parameters and their TOML file format (ARCHITECTURE.md)."""

from __future__ import annotations

import math
import os
from dataclasses import asdict, dataclass, field, fields

from icarus_vision.fileio import atomic_write_text, read_toml
from icarus_vision.validation import check_table, require_table

GRAVITY = 9.81


class QuadError(ValueError):
    """A quadrotor file or parameter set is malformed; the message names the file and the key."""


@dataclass(frozen=True)
class CameraParams:
    """The FPV camera mounted on the drone (OpenCV optical frame, pitched up by ``uptilt_deg``)."""

    width: int = 320
    """Image width, pixels."""
    height: int = 240
    """Image height, pixels."""
    hfov_deg: float = 90.0
    """Horizontal field of view, degrees."""
    uptilt_deg: float = 20.0
    """Camera pitched up from the body x axis, degrees."""
    rate_hz: float = 30.0
    """Frame rate, Hz."""
    distortion: str = "none"
    """Lens model: ``none`` (pinhole), ``radtan`` (OpenCV's radial-tangential) or ``fisheye``
    (OpenCV's fisheye); K stays the pinhole one of ``hfov_deg`` (render/distortion.py)."""
    dist_coeffs: tuple[float, ...] = ()
    """The model's coefficients: radtan ``[k1, k2, p1, p2]`` or ``[k1, k2, p1, p2, k3]``,
    fisheye ``[k1, k2, k3, k4]``, none ``[]``."""


@dataclass(frozen=True)
class QuadParams:
    """A racing quadrotor. Defaults: a 0.5 kg 5-inch-class racer with thrust-to-weight 4."""

    name: str = "racer-500g"
    """Identifier used in reports."""
    mass: float = 0.5
    """Mass, kg."""
    inertia: tuple[float, float, float] = (0.0023, 0.0023, 0.004)
    """Diagonal inertia (body x, y, z), kg m²."""
    arm_length: float = 0.12
    """Motor arm length, m."""
    thrust_to_weight: float = 4.0
    """T_max / (m g)."""
    max_rate: tuple[float, float, float] = (10.0, 10.0, 4.0)
    """Body-rate command limits (roll, pitch, yaw), rad/s."""
    motor_tau: float = 0.03
    """First-order time constant of the thrust and body-rate response, s."""
    drag: tuple[float, float, float] = (0.3, 0.3, 0.5)
    """Linear drag in the body frame, N / (m/s) of airspeed."""
    radius: float = 0.15
    """Collision sphere radius, m."""
    camera: CameraParams = field(default_factory=CameraParams)
    """FPV camera."""

    def __post_init__(self) -> None:
        validate_quad(self)

    @property
    def thrust_max(self) -> float:
        """Maximum collective thrust T_max, N."""
        return self.thrust_to_weight * self.mass * GRAVITY

    @property
    def hover_thrust_action(self) -> float:
        """The thrust action in [-1, 1] that balances gravity."""
        return 2.0 / self.thrust_to_weight - 1.0


def validate_quad(q: QuadParams, source: str = "<memory>") -> None:
    """Raise QuadError when a parameter is non-finite or out of its physical range."""

    def pos(name: str, v) -> None:
        vals = v if isinstance(v, tuple) else (v,)
        for x in vals:
            if isinstance(x, bool) or not isinstance(x, int | float) or not math.isfinite(x):
                raise QuadError(f"{source}: {name} must be finite numbers, got {v!r}")
            if x <= 0:
                raise QuadError(f"{source}: {name} must be > 0, got {v!r}")

    for name in ("mass", "arm_length", "motor_tau", "radius", "inertia", "max_rate"):
        pos(name, getattr(q, name))
    pos("thrust_to_weight", q.thrust_to_weight)
    if q.thrust_to_weight <= 1.0:
        raise QuadError(f"{source}: thrust_to_weight must be > 1 to fly, got {q.thrust_to_weight}")
    for name, n in (("inertia", 3), ("max_rate", 3), ("drag", 3)):
        if len(getattr(q, name)) != n:
            raise QuadError(f"{source}: {name} must have {n} values")
    for x in q.drag:
        if not math.isfinite(x) or x < 0:
            raise QuadError(f"{source}: drag must be finite and >= 0, got {q.drag!r}")
    c = q.camera
    for name in ("width", "height"):
        v = getattr(c, name)
        if isinstance(v, bool) or not isinstance(v, int) or v < 8:
            raise QuadError(f"{source}: camera.{name} must be an integer >= 8, got {v!r}")
    pos("camera.hfov_deg", c.hfov_deg)
    pos("camera.rate_hz", c.rate_hz)
    if c.hfov_deg >= 170:
        raise QuadError(f"{source}: camera.hfov_deg must be < 170, got {c.hfov_deg}")
    if not math.isfinite(c.uptilt_deg) or abs(c.uptilt_deg) > 90:
        raise QuadError(f"{source}: camera.uptilt_deg must be within ±90, got {c.uptilt_deg}")
    from icarus_vision.render.distortion import check_distortion

    problem = check_distortion(c.distortion, tuple(c.dist_coeffs))
    if problem is not None:
        raise QuadError(f"{source}: camera.{problem}")


def quad_from_dict(data: dict, source: str = "<memory>") -> QuadParams:
    """Build QuadParams from a parsed TOML table; missing keys take the defaults."""
    data = dict(require_table(data, source, QuadError))
    cam = require_table(data.pop("camera", {}), f"{source} [camera]", QuadError)
    kwargs = check_table(QuadParams, data, source, QuadError)
    cam_kwargs = check_table(CameraParams, cam, f"{source} [camera]", QuadError)
    try:
        camera = CameraParams(**cam_kwargs)
        q = QuadParams.__new__(QuadParams)
        object.__setattr__(q, "camera", camera)
        defaults = QuadParams()
        for f in fields(QuadParams):
            if f.name != "camera":
                object.__setattr__(q, f.name, kwargs.get(f.name, getattr(defaults, f.name)))
    except TypeError as e:
        raise QuadError(f"{source}: {e}") from None
    validate_quad(q, source)
    return q


def load_quad(path: str | os.PathLike) -> QuadParams:
    """Load a quadrotor TOML file; QuadError names the file on any problem."""
    data = read_toml(path, "quadrotor", QuadError)
    return quad_from_dict(data, source=str(path))


def quad_to_toml(q: QuadParams) -> str:
    d = asdict(q)
    cam = d.pop("camera")

    def fmt(v) -> str:
        if isinstance(v, str):
            return f'"{v}"'
        if isinstance(v, list | tuple):
            return "[" + ", ".join(repr(float(x)) for x in v) + "]"
        return repr(v)

    lines = [f"{k} = {fmt(v)}" for k, v in d.items()]
    if cam["distortion"] == "none":  # a pinhole camera: written as before the lens existed
        del cam["distortion"], cam["dist_coeffs"]
    lines += ["", "[camera]"] + [f"{k} = {fmt(v)}" for k, v in cam.items()]
    return "\n".join(lines) + "\n"


def save_quad(q: QuadParams, path: str | os.PathLike) -> None:
    atomic_write_text(path, quad_to_toml(q))
