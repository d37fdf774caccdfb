"""Seeded race layouts with the ranges and motifs of real tracks (``race_track``).

``random_track`` keeps its gentle classic ranges (and its draws under every seed); this module draws
the wider distribution that racing policies train and are measured on. At ``difficulty`` 1 (the
documented ranges, the keyword defaults of :class:`LayoutRanges`):

* spacing 3–15 m between consecutive gates; the course turns by up to ±120° after a gate;
* each gate is turned up to ±60° from the direction it is approached;
* gate centres 0.5–6 m high (never so low that the frame touches the ground), up to ±3 m between
  neighbours; openings 0.8–1.5 m;
* with probability ``motif_prob`` the next element is a motif drawn uniformly from ``MOTIFS``
  instead of a single gate (``loop`` drawn there, or a motif that does not fit, gives a single
  gate, so each of the four below comes with probability ``motif_prob / 5``): ``split-s`` (a high gate, then a
  gate directly below it passed the other way), ``hairpin`` (the
  previous gate flown again in the opposite direction), ``slalom`` (a row of parallel gates facing
  down the course, offset alternately left and right, so the path zigzags), ``spiral`` (gates
  round a climbing or descending circle); and ``loop``: with probability ``motif_prob / 4``
  (for an even gate count of at least 6) the whole track is a closed circuit flown two laps.

``difficulty`` in [0, 1] moves every range linearly from the classic one (0: spacing 4–8 m, turns
±60°, gates ±15° off their approach, 1–3 m high with ≤ 1 m changes, 1 m openings, no motifs) to
the full one (1), so a curriculum can widen the layouts as it promotes.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from icarus_vision.sim.track import DEFAULT_FRAME_WIDTH, Gate, Track

MOTIFS = ("split-s", "hairpin", "slalom", "spiral", "loop")
GROUND_CLEARANCE = 0.3  # m between the ground and the bottom of a gate's frame
STACK_GAP = 1.0  # m of air between the frames of two stacked gates (split-s)


@dataclass(frozen=True)
class LayoutRanges:
    """Ranges of one layout distribution (the defaults are the full, difficulty-1 ranges)."""

    spacing: tuple[float, float] = (3.0, 15.0)
    """Distance between consecutive gate centres, m."""
    max_turn_deg: float = 120.0
    """Largest change of course direction after a gate, degrees."""
    yaw_offset_deg: float = 60.0
    """Largest angle between a gate's passage direction and the direction it is approached from."""
    height: tuple[float, float] = (0.5, 6.0)
    """Gate centre height, m (raised where the frame would otherwise reach the ground)."""
    max_climb: float = 3.0
    """Largest height change between neighbouring gates, m."""
    size: tuple[float, float] = (0.8, 1.5)
    """Side of the square opening, m."""
    motif_prob: float = 0.5
    """Probability that the next element is a motif instead of a single gate."""
    min_separation: float = 2.5
    """Smallest distance between the centres of two different physical gates, m (a split-s
    stacks its two gates closer, with ``STACK_GAP`` of air between their frames)."""


CLASSIC = LayoutRanges((4.0, 8.0), 60.0, 15.0, (1.0, 3.0), 1.0, (1.0, 1.0), 0.0, 3.0)
FULL = LayoutRanges()


def layout_ranges(difficulty: float) -> LayoutRanges:
    """Ranges at ``difficulty`` in [0, 1]: linear from the classic ranges (0) to the full ones (1)."""
    if not 0.0 <= difficulty <= 1.0:
        raise ValueError(f"difficulty must be in [0, 1], got {difficulty}")

    def mix(a, b):
        if isinstance(a, tuple):
            return tuple(mix(x, y) for x, y in zip(a, b, strict=True))
        return a + (b - a) * difficulty

    return LayoutRanges(
        **{k: mix(getattr(CLASSIC, k), getattr(FULL, k)) for k in LayoutRanges.__annotations__}
    )


def _wrap_deg(a: float) -> float:
    """An angle in degrees wrapped to [-180, 180)."""
    return (a + 180.0) % 360.0 - 180.0


@dataclass
class _Cursor:
    """Where the course stands after the last gate: its position and the direction of travel."""

    x: float
    y: float
    z: float
    heading: float  # radians: the passage direction of the last gate


class _Builder:
    """Appends gates to a course while checking ground clearance and separation."""

    def __init__(self, rng: np.random.Generator, r: LayoutRanges) -> None:
        self.rng, self.r = rng, r
        self.gates: list[Gate] = []
        self.cur = _Cursor(0.0, 0.0, float(rng.uniform(*r.height)), 0.0)

    def size(self) -> float:
        return float(self.rng.uniform(*self.r.size))

    def clamp_z(self, z: float, size: float) -> float:
        low = max(self.r.height[0], size / 2 + DEFAULT_FRAME_WIDTH + GROUND_CLEARANCE)
        return min(max(z, low), max(self.r.height[1], low))

    def fits(self, pos: tuple[float, float, float], same_as: Gate | None = None) -> bool:
        """True when ``pos`` keeps clear of the start and of every other physical gate."""
        p = np.asarray(pos)
        if math.hypot(p[0], p[1]) < 3.0:
            return False
        for g in self.gates:
            if same_as is not None and g.pos == same_as.pos:
                continue
            if np.linalg.norm(p - g.pos) < self.r.min_separation:
                return False
        return True

    def add(self, gate: Gate) -> None:
        gate = Gate(gate.pos, _wrap_deg(gate.yaw_deg), gate.size, gate.frame_width)
        self.gates.append(gate)
        self.cur = _Cursor(*gate.pos, heading=gate.yaw)

    def step_pos(self, dist: float, turn: float, climb: float, size: float):
        """Position ``dist`` ahead along the course turned by ``turn`` and its travel direction."""
        c = self.cur
        direction = c.heading + turn
        x, y = c.x + dist * math.cos(direction), c.y + dist * math.sin(direction)
        return (x, y, self.clamp_z(c.z + climb, size)), direction

    # -- elements ------------------------------------------------------------------------------
    def single(self) -> bool:
        r, rng = self.r, self.rng
        first = not self.gates
        dist = float(rng.uniform(*r.spacing))
        turn = 0.0 if first else math.radians(rng.uniform(-r.max_turn_deg, r.max_turn_deg))
        climb = float(rng.uniform(-r.max_climb, r.max_climb))
        offset = math.radians(rng.uniform(-r.yaw_offset_deg, r.yaw_offset_deg))
        size = self.size()
        pos, direction = self.step_pos(dist, turn, climb, size)
        if first:
            pos = (pos[0], 0.0, pos[2])
        if not self.fits(pos):
            return False
        self.add(Gate(pos, math.degrees(direction + offset), size))
        return True

    def split_s(self) -> bool:
        """A high gate, then a gate directly below it passed the opposite way (two passages)."""
        r, rng = self.r, self.rng
        top, low = self.size(), self.size()
        z_low = low / 2 + DEFAULT_FRAME_WIDTH + GROUND_CLEARANCE + float(rng.uniform(0.0, 1.0))
        z_top = z_low + (top + low) / 2 + 2 * DEFAULT_FRAME_WIDTH + STACK_GAP
        if z_top > max(r.height[1], 3.0):
            return False
        dist = float(rng.uniform(*r.spacing))
        turn = math.radians(rng.uniform(-r.max_turn_deg, r.max_turn_deg)) if self.gates else 0.0
        offset = math.radians(rng.uniform(-r.yaw_offset_deg, r.yaw_offset_deg))
        (x, y, _), direction = self.step_pos(dist, turn, 0.0, top)
        if not self.gates:
            y = 0.0
        if not (self.fits((x, y, z_top)) and self.fits((x, y, z_low))):
            return False
        self.add(Gate((x, y, z_top), math.degrees(direction + offset), top))
        self.add(Gate((x, y, z_low), math.degrees(direction + offset) + 180.0, low))
        return True

    def hairpin(self) -> bool:
        """The last gate again, in the opposite direction."""
        last = self.gates[-1]
        self.add(Gate(last.pos, last.yaw_deg + 180.0, last.size, last.frame_width))
        return True

    def slalom(self, count: int) -> bool:
        """``count`` parallel gates facing down the course, offset alternately left and right."""
        rng, c = self.rng, self.cur
        axis = c.heading
        step = float(
            rng.uniform(max(3.0, self.r.spacing[0]), max(4.0, min(8.0, self.r.spacing[1])))
        )
        # Lateral offset: the zigzag turns each gate's approach by up to yaw_offset_deg.
        half = 0.5 * step * math.tan(math.radians(min(self.r.yaw_offset_deg, 50.0)))
        width = float(rng.uniform(0.3, 1.0)) * half
        side = 1.0 if rng.random() < 0.5 else -1.0
        climb = float(rng.uniform(-1.0, 1.0)) * min(self.r.max_climb, 1.0)
        size = self.size()
        new: list[Gate] = []
        for k in range(1, count + 1):
            along, lateral = k * step, side * width * (1 if k % 2 else -1)
            x = c.x + along * math.cos(axis) - lateral * math.sin(axis)
            y = c.y + along * math.sin(axis) + lateral * math.cos(axis)
            pos = (x, y, self.clamp_z(c.z + k * climb, size))
            close = any(
                np.linalg.norm(np.subtract(pos, g.pos)) < self.r.min_separation for g in new
            )
            if close or not self.fits(pos):
                return False
            new.append(Gate(pos, math.degrees(axis), size))
        for g in new:
            self.add(g)
        return True

    def spiral(self, count: int) -> bool:
        """``count`` gates round a circle that climbs (or descends), each facing along it."""
        rng, c = self.rng, self.cur
        radius = float(rng.uniform(3.0, 6.0))
        sense = 1.0 if rng.random() < 0.5 else -1.0
        arc = math.radians(float(rng.uniform(60.0, 100.0)))  # between neighbouring gates
        climb = float(rng.uniform(0.5, 1.0)) * min(self.r.max_climb, 1.5)
        climb *= 1.0 if c.z < sum(self.r.height) / 2 else -1.0
        size = self.size()
        # Circle centre to the side of the current heading, the course entering it tangentially.
        cx = c.x - sense * radius * math.sin(c.heading)
        cy = c.y + sense * radius * math.cos(c.heading)
        phase = math.atan2(c.y - cy, c.x - cx)
        new: list[Gate] = []
        for k in range(1, count + 1):
            a = phase + sense * k * arc
            pos = (cx + radius * math.cos(a), cy + radius * math.sin(a), c.z + k * climb)
            lo = size / 2 + DEFAULT_FRAME_WIDTH + GROUND_CLEARANCE
            if not lo <= pos[2] <= max(self.r.height[1], lo) or not self.fits(pos):
                return False
            if any(np.linalg.norm(np.subtract(pos, g.pos)) < self.r.min_separation for g in new):
                return False
            new.append(Gate(pos, math.degrees(a + sense * math.pi / 2), size))
        for g in new:
            self.add(g)
        return True


def _loop_track(rng: np.random.Generator, r: LayoutRanges, n_gates: int, name: str) -> Track | None:
    """A closed circuit of ``n_gates / 2`` gates flown two laps (an ellipse with wobble)."""
    k = n_gates // 2
    a = float(rng.uniform(max(4.0, r.spacing[0] * k / 6), max(5.0, r.spacing[1] * k / 6)))
    b = a * float(rng.uniform(0.5, 1.0))
    sense = 1.0 if rng.random() < 0.5 else -1.0
    ang = np.linspace(0.0, 2 * math.pi, k, endpoint=False) + rng.uniform(-0.2, 0.2, k)
    # Start just outside the ellipse at angle -pi/2, heading +x along its tangent.
    x = a * np.sin(ang)
    y = sense * b * (1 - np.cos(ang))
    base = float(rng.uniform(*r.height))
    z = base + rng.uniform(-1, 1, k) * min(r.max_climb, 1.5)
    dx = a * np.cos(ang)
    dy = sense * b * np.sin(ang)
    sizes = rng.uniform(*r.size, k)
    offsets = rng.uniform(-1, 1, k) * min(r.yaw_offset_deg, 20.0)
    b_ = _Builder(rng, r)
    gates = []
    chord = np.hypot(np.diff(np.append(x, x[0])), np.diff(np.append(y, y[0])))
    if chord.max() > r.spacing[1] or chord.min() < max(r.spacing[0], r.min_separation):
        return None
    for i in range(k):
        zi = b_.clamp_z(float(z[i]), float(sizes[i]))
        pos = (float(x[i]) + 3.5, float(y[i]), zi)
        if not b_.fits(pos):
            return None
        b_.add(
            Gate(pos, math.degrees(math.atan2(dy[i], dx[i])) + float(offsets[i]), float(sizes[i]))
        )
        gates.append(b_.gates[-1])
    return Track(name, tuple(gates), (0.0, 0.0, 0.2), 0.0, laps=2)


def race_track(
    n_gates: int,
    seed: int | np.random.Generator | None = None,
    *,
    difficulty: float = 1.0,
    ranges: LayoutRanges | None = None,
    max_tries: int = 1000,
) -> Track:
    """Draw a race layout of ``n_gates`` gate passages.

    Args:
        n_gates: gate passages in the episode, >= 1 (a ``loop`` track flies n/2 gates twice).
        seed: int seed or a numpy Generator (consumed).
        difficulty: 0 (classic ranges) to 1 (full ranges); ignored when ``ranges`` is given.
        ranges: explicit ranges.

    Returns:
        A Track named ``race-<n>-<seed>`` starting at (0, 0, 0.2) facing +x.
    """
    if n_gates < 1:
        raise ValueError(f"n_gates must be >= 1, got {n_gates}")
    r = ranges if ranges is not None else layout_ranges(difficulty)
    rng = seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)
    name = f"race-{n_gates}-{seed if isinstance(seed, int) else 'rng'}"
    for _ in range(max_tries):
        motif_draw = rng.random(n_gates)
        motif_pick = rng.integers(0, len(MOTIFS), n_gates)
        if n_gates >= 6 and n_gates % 2 == 0 and motif_draw[0] < r.motif_prob / 4:
            track = _loop_track(rng, r, n_gates, name)
            if track is not None:
                return track
            continue
        b = _Builder(rng, r)
        ok = True
        i = 0
        while ok and len(b.gates) < n_gates:
            left = n_gates - len(b.gates)
            motif = MOTIFS[motif_pick[i]] if b.gates and motif_draw[i] < r.motif_prob else None
            i = min(i + 1, n_gates - 1)
            placed = False
            if motif == "split-s" and left >= 2:
                placed = b.split_s()
            elif motif == "hairpin":
                placed = b.hairpin()
            elif motif == "slalom" and left >= 2:
                placed = b.slalom(min(left, int(rng.integers(3, 6))))
            elif motif == "spiral" and left >= 2:
                placed = b.spiral(min(left, int(rng.integers(3, 5))))
            ok = placed or b.single()  # a motif that does not fit here gives way to a gate
        if ok:
            return Track(name, tuple(b.gates), (0.0, 0.0, 0.2), 0.0)
    raise RuntimeError(f"could not draw a {n_gates}-gate race track in {max_tries} tries")


def track_motifs(track: Track) -> set[str]:
    """The motifs recognisable in a track's geometry (for tests and reports)."""
    found: set[str] = set()
    g = track.gates
    if track.laps > 1:
        found.add("loop")
    for a, b in zip(g, g[1:], strict=False):
        same_xy = math.hypot(a.pos[0] - b.pos[0], a.pos[1] - b.pos[1]) < 0.01
        opposite = abs(_wrap_deg(a.yaw_deg - b.yaw_deg)) > 179.0
        if same_xy and opposite:
            found.add("hairpin" if abs(a.pos[2] - b.pos[2]) < 0.01 else "split-s")
    for a, b, c in zip(g, g[1:], g[2:], strict=False):
        turn1, turn2 = _wrap_deg(b.yaw_deg - a.yaw_deg), _wrap_deg(c.yaw_deg - b.yaw_deg)
        if abs(turn1) < 1e-6 and abs(turn2) < 1e-6:
            found.add("slalom")
        dz1, dz2 = b.pos[2] - a.pos[2], c.pos[2] - b.pos[2]
        if (
            abs(dz1) > 0.1
            and abs(dz1 - dz2) < 1e-6
            and abs(turn1 - turn2) < 1e-6
            and abs(turn1) > 1
        ):
            found.add("spiral")
    return found


__all__ = [
    "CLASSIC",
    "FULL",
    "MOTIFS",
    "LayoutRanges",
    "layout_ranges",
    "race_track",
    "track_motifs",
]
