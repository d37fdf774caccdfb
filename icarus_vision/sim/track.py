"""Race tracks: gates, start pose, bounds, and the TOML file format of ARCHITECTURE.md.

Frames: world is z-up. A gate's frame has x along the direction of passage (``yaw_deg``), y left,
z up; its opening is the square |y| <= size/2, |z| <= size/2 in the plane x = 0.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field, replace

import numpy as np

from icarus_vision.fileio import atomic_write_text, read_toml
from icarus_vision.validation import require_list, require_table

DEFAULT_GATE_SIZE = 1.0
DEFAULT_FRAME_WIDTH = 0.1
BOUNDS_MARGIN = 5.0
SAME_GATE_TOL = 0.01  # m: entries whose centres are this close are one physical gate

_TOP_KEYS = {"name", "laps", "start", "defaults", "bounds", "gates"}
_START_KEYS = {"pos", "yaw_deg"}
_GATE_KEYS = {"pos", "yaw_deg", "size", "frame_width"}
_DEFAULT_KEYS = {"yaw_deg", "size", "frame_width"}
_BOUNDS_KEYS = {"min", "max"}


class TrackError(ValueError):
    """A track file or track definition is malformed; the message names the file and the gate."""


@dataclass(frozen=True)
class Gate:
    """One gate passage.

    Attributes:
        pos: (3,) world position of the opening's centre, metres.
        yaw_deg: heading of the passage direction about world z, degrees (0 => pass along +x).
        size: side of the square inner opening, metres.
        frame_width: width of the bars around the opening, metres (bars are as deep as wide).
    """

    pos: tuple[float, float, float]
    yaw_deg: float = 0.0
    size: float = DEFAULT_GATE_SIZE
    frame_width: float = DEFAULT_FRAME_WIDTH

    @property
    def yaw(self) -> float:
        """Heading in radians."""
        return math.radians(self.yaw_deg)

    @property
    def normal(self) -> np.ndarray:
        """(3,) world unit vector of the passage direction."""
        return np.array([math.cos(self.yaw), math.sin(self.yaw), 0.0])

    def corners(self) -> np.ndarray:
        """Inner-opening corners in world frame.

        Returns:
            (4, 3) float64, order TL, TR, BR, BL as seen by a drone approaching along +x (gate frame).
        """
        h = self.size / 2.0
        local = np.array([[0, h, h], [0, -h, h], [0, -h, -h], [0, h, -h]], dtype=float)
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        rot = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        return local @ rot.T + np.asarray(self.pos)


@dataclass(frozen=True)
class Track:
    """A race course.

    Attributes:
        name: short identifier.
        gates: gate passages of one lap, in racing order.
        start_pos: (3,) start position of the drone's centre, metres.
        start_yaw_deg: start heading, degrees.
        laps: how many times the gate list is flown.
        bounds_min: (3,) lower corner of the allowed box; leaving it is a crash.
        bounds_max: (3,) upper corner of the allowed box.
    """

    name: str
    gates: tuple[Gate, ...]
    start_pos: tuple[float, float, float] = (0.0, 0.0, 0.2)
    start_yaw_deg: float = 0.0
    laps: int = 1
    bounds_min: tuple[float, float, float] | None = None
    bounds_max: tuple[float, float, float] | None = None
    source: str = field(default="<memory>", compare=False)

    def __post_init__(self) -> None:
        validate_track(self)
        if self.bounds_min is None or self.bounds_max is None:
            lo, hi = default_bounds(self.start_pos, [g.pos for g in self.gates])
            object.__setattr__(self, "bounds_min", self.bounds_min or lo)
            object.__setattr__(self, "bounds_max", self.bounds_max or hi)

    @property
    def passages(self) -> tuple[Gate, ...]:
        """Every gate passage over all laps, in order."""
        return self.gates * self.laps

    @property
    def num_passages(self) -> int:
        return len(self.gates) * self.laps

    def physical_gates(self) -> tuple[Gate, ...]:
        """Distinct physical gates: entries with centres within 1 cm are one gate, built once."""
        out: list[Gate] = []
        for g in self.gates:
            if not any(np.linalg.norm(np.subtract(g.pos, o.pos)) < SAME_GATE_TOL for o in out):
                out.append(g)
        return tuple(out)

    def with_num_gates(self, n: int) -> Track:
        """The first ``n`` gates of this track (one lap), for the curriculum."""
        if not 1 <= n <= len(self.gates):
            raise ValueError(f"num gates must be in [1, {len(self.gates)}], got {n}")
        return replace(self, gates=self.gates[:n], laps=1, bounds_min=None, bounds_max=None)

    def with_laps(self, laps: int) -> Track:
        if laps < 1:
            raise ValueError(f"laps must be >= 1, got {laps}")
        return replace(self, laps=laps)


def default_bounds(start, gate_positions) -> tuple[tuple, tuple]:
    """Box around the start and gates with a 5 m margin, floor at z = 0."""
    pts = np.array([start, *gate_positions], dtype=float)
    lo = pts.min(axis=0) - BOUNDS_MARGIN
    hi = pts.max(axis=0) + BOUNDS_MARGIN
    lo[2] = 0.0
    return tuple(float(v) for v in lo), tuple(float(v) for v in hi)


def _finite(x: float, what: str, where: str) -> float:
    if isinstance(x, bool) or not isinstance(x, int | float) or not math.isfinite(x):
        raise TrackError(f"{where}: {what} must be a finite number, got {x!r}")
    return float(x)


def _vec3(v, what: str, where: str) -> tuple[float, float, float]:
    if not isinstance(v, list | tuple) or len(v) != 3:
        raise TrackError(f"{where}: {what} must be a list of 3 numbers, got {v!r}")
    return tuple(_finite(x, what, where) for x in v)  # type: ignore[return-value]


def inside_gate_frame(point, gate: Gate, margin: float = 0.0) -> bool:
    """True when ``point`` (world, (3,)) lies inside one of the gate's frame bars (+ margin)."""
    from icarus_vision.sim.rules import gate_bar_distance  # local: rules imports this module

    d = gate_bar_distance(
        np.asarray(point, float)[None, None],
        np.asarray(gate.pos, float)[None, None],
        np.array([[gate.yaw]]),
        np.array([[gate.size]]),
        np.array([[gate.frame_width]]),
    )
    return bool(d[0, 0] <= margin)


def start_inside_frames(track: Track) -> np.ndarray:
    """(G,) bool: whether the start position lies inside each gate's frame bars."""
    from icarus_vision.sim.rules import gate_bar_distance  # local: rules imports this module

    g = track.gates
    d = gate_bar_distance(
        np.asarray(track.start_pos, float)[None],
        np.array([x.pos for x in g], float)[None],
        np.array([[x.yaw for x in g]]),
        np.array([[x.size for x in g]]),
        np.array([[x.frame_width for x in g]]),
    )
    return d[0] <= 0.0


def _gates_plainly_valid(gates) -> bool:
    """Fast vectorised check that every gate field is a finite number and sizes are positive."""
    try:
        rows = [(*g.pos, g.yaw_deg, g.size, g.frame_width) for g in gates]
        if any(isinstance(v, bool | str) for r in rows for v in r):
            return False
        a = np.array(rows, dtype=float)
    except (TypeError, ValueError):
        return False
    return a.shape == (len(gates), 6) and bool(np.isfinite(a).all() and (a[:, 4:] > 0).all())


def validate_track(track: Track) -> None:
    """Check a track; raise TrackError naming the source file and the gate."""
    src = track.source
    if not track.gates:
        raise TrackError(f"{src}: a track needs at least one gate")
    if not isinstance(track.laps, int) or track.laps < 1:
        raise TrackError(f"{src}: laps must be an integer >= 1, got {track.laps!r}")
    _vec3(list(track.start_pos), "start.pos", f"{src} [start]")
    _finite(track.start_yaw_deg, "start.yaw_deg", f"{src} [start]")
    if not _gates_plainly_valid(track.gates):  # slow path only to name the offending gate
        for i, g in enumerate(track.gates):
            where = f"{src} gate {i}"
            _vec3(list(g.pos), "pos", where)
            _finite(g.yaw_deg, "yaw_deg", where)
            if _finite(g.size, "size", where) <= 0:
                raise TrackError(f"{where}: size must be > 0, got {g.size}")
            if _finite(g.frame_width, "frame_width", where) <= 0:
                raise TrackError(f"{where}: frame_width must be > 0, got {g.frame_width}")
    inside = start_inside_frames(track)
    if inside.any():
        i = int(np.flatnonzero(inside)[0])
        raise TrackError(
            f"{src} gate {i}: the start position {track.start_pos} is inside its frame"
        )
    if track.bounds_min is not None and track.bounds_max is not None:
        lo = np.array(_vec3(list(track.bounds_min), "bounds.min", f"{src} [bounds]"))
        hi = np.array(_vec3(list(track.bounds_max), "bounds.max", f"{src} [bounds]"))
        if np.any(lo >= hi):
            raise TrackError(f"{src} [bounds]: min must be below max on every axis")
        for i, g in enumerate(track.gates):
            if np.any(np.array(g.pos) < lo) or np.any(np.array(g.pos) > hi):
                raise TrackError(f"{src} gate {i}: pos {g.pos} is outside the bounds")
        if np.any(np.array(track.start_pos) < lo) or np.any(np.array(track.start_pos) > hi):
            raise TrackError(f"{src} [start]: pos {track.start_pos} is outside the bounds")


def _check_keys(table: dict, allowed: set[str], where: str) -> None:
    unknown = sorted(set(table) - allowed)
    if unknown:
        raise TrackError(f"{where}: unknown key(s) {unknown}; allowed: {sorted(allowed)}")


def track_from_dict(data: dict, source: str = "<memory>") -> Track:
    """Build a Track from the parsed TOML structure of ARCHITECTURE.md."""
    require_table(data, source, TrackError)
    _check_keys(data, _TOP_KEYS, source)
    if "name" not in data:
        raise TrackError(f"{source}: missing required key 'name'")
    start = require_table(data.get("start", {}), f"{source} [start]", TrackError)
    if "pos" not in start:
        raise TrackError(f"{source}: missing required key 'start.pos'")
    _check_keys(start, _START_KEYS, f"{source} [start]")
    defaults = require_table(data.get("defaults", {}), f"{source} [defaults]", TrackError)
    _check_keys(defaults, _DEFAULT_KEYS, f"{source} [defaults]")
    if not data.get("gates"):
        raise TrackError(f"{source}: missing required [[gates]] (at least one gate)")
    gates_raw = require_list(data["gates"], f"{source} [[gates]]", TrackError)
    gates = []
    for i, g in enumerate(gates_raw):
        where = f"{source} gate {i}"
        if not isinstance(g, dict):
            raise TrackError(f"{where}: expected a table")
        _check_keys(g, _GATE_KEYS, where)
        if "pos" not in g:
            raise TrackError(f"{where}: missing required key 'pos'")
        merged = {**defaults, **g}
        gates.append(
            Gate(
                pos=_vec3(merged["pos"], "pos", where),
                yaw_deg=_finite(merged.get("yaw_deg", 0.0), "yaw_deg", where),
                size=_finite(merged.get("size", DEFAULT_GATE_SIZE), "size", where),
                frame_width=_finite(
                    merged.get("frame_width", DEFAULT_FRAME_WIDTH), "frame_width", where
                ),
            )
        )
    bounds = data.get("bounds")
    lo = hi = None
    if bounds is not None:
        require_table(bounds, f"{source} [bounds]", TrackError)
        _check_keys(bounds, _BOUNDS_KEYS, f"{source} [bounds]")
        if "min" not in bounds or "max" not in bounds:
            raise TrackError(f"{source} [bounds]: needs both 'min' and 'max'")
        lo = _vec3(bounds["min"], "bounds.min", f"{source} [bounds]")
        hi = _vec3(bounds["max"], "bounds.max", f"{source} [bounds]")
    laps = data.get("laps", 1)
    if isinstance(laps, bool) or not isinstance(laps, int) or laps < 1:
        raise TrackError(f"{source}: laps must be an integer >= 1, got {laps!r}")
    name = data["name"]
    if not isinstance(name, str) or not name:
        raise TrackError(f"{source}: name must be a non-empty string")
    return Track(
        name=name,
        gates=tuple(gates),
        start_pos=_vec3(start["pos"], "start.pos", f"{source} [start]"),
        start_yaw_deg=_finite(start.get("yaw_deg", 0.0), "start.yaw_deg", f"{source} [start]"),
        laps=laps,
        bounds_min=lo,
        bounds_max=hi,
        source=source,
    )


def load_track(path: str | os.PathLike) -> Track:
    """Load a track TOML file; TrackError names the file (and gate) on any problem."""
    data = read_toml(path, "track", TrackError)
    return track_from_dict(data, source=str(path))


def _fmt(v) -> str:
    return "[" + ", ".join(repr(float(x)) for x in v) + "]"


def track_to_toml(track: Track) -> str:
    """Serialise a track to the TOML format (round-trips through load_track)."""
    lines = [f'name = "{track.name}"', f"laps = {track.laps}", "", "[start]"]
    lines += [f"pos = {_fmt(track.start_pos)}", f"yaw_deg = {float(track.start_yaw_deg)!r}", ""]
    lines += ["[bounds]", f"min = {_fmt(track.bounds_min)}", f"max = {_fmt(track.bounds_max)}"]
    for g in track.gates:
        lines += ["", "[[gates]]", f"pos = {_fmt(g.pos)}", f"yaw_deg = {float(g.yaw_deg)!r}"]
        lines += [f"size = {float(g.size)!r}", f"frame_width = {float(g.frame_width)!r}"]
    return "\n".join(lines) + "\n"


def save_track(track: Track, path: str | os.PathLike) -> None:
    """Write a track TOML file atomically."""
    atomic_write_text(path, track_to_toml(track))
