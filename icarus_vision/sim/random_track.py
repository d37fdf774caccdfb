"""Seeded procedural tracks for training and tests.

Layout rules (all documented ranges are the keyword defaults of ``random_track``):

* the first gate lies ``spacing`` ahead of the start along +x (start heading 0);
* each next gate is ``spacing`` (uniform in [4, 8] m) from the previous one, in a direction that
  turns by at most ``max_turn_deg`` (±60°) from the previous gate's heading;
* each gate faces the direction it is approached from, plus a yaw offset of at most ±15°;
* gate centres stay in [1.0, 3.0] m height with at most 1 m change between neighbours;
* gates stay at least ``min_separation`` (3 m) apart; a draw that breaks this is re-drawn.
"""

from __future__ import annotations

import math

import numpy as np

from icarus_vision.sim.track import Gate, Track


def random_track(
    n_gates: int,
    seed: int | np.random.Generator | None = None,
    *,
    spacing: tuple[float, float] = (4.0, 8.0),
    max_turn_deg: float = 60.0,
    yaw_offset_deg: float = 15.0,
    height: tuple[float, float] = (1.0, 3.0),
    max_climb: float = 1.0,
    min_separation: float = 3.0,
    size: float = 1.0,
    frame_width: float = 0.1,
    max_tries: int = 1000,
) -> Track:
    """Draw a flyable random track of ``n_gates`` gates.

    Args:
        n_gates: number of gates, >= 1.
        seed: int seed or a numpy Generator (consumed).

    Returns:
        A one-lap Track named ``random-<n>-<seed>`` starting at (0, 0, 0.2) facing +x.
    """
    if n_gates < 1:
        raise ValueError(f"n_gates must be >= 1, got {n_gates}")
    rng = seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)
    start = np.zeros(3)
    for _ in range(max_tries):
        gates: list[Gate] = []
        prev = np.array([0.0, 0.0, rng.uniform(*height)])
        heading = 0.0
        ok = True
        for i in range(n_gates):
            d = rng.uniform(*spacing)
            turn = 0.0 if i == 0 else math.radians(rng.uniform(-max_turn_deg, max_turn_deg))
            direction = heading + turn
            z = float(np.clip(prev[2] + rng.uniform(-max_climb, max_climb), *height))
            pos = np.array([prev[0] + d * math.cos(direction), prev[1] + d * math.sin(direction), z])
            if i == 0:
                pos[1] = 0.0
            if any(np.linalg.norm(pos[:2] - np.array(g.pos[:2])) < min_separation for g in gates):
                ok = False
                break
            if np.linalg.norm(pos[:2] - start[:2]) < min_separation:
                ok = False
                break
            yaw = direction + math.radians(rng.uniform(-yaw_offset_deg, yaw_offset_deg))
            gates.append(
                Gate(tuple(float(v) for v in pos), math.degrees(yaw), size, frame_width)
            )
            prev, heading = pos, yaw
        if ok:
            label = seed if isinstance(seed, int) else "rng"
            return Track(f"random-{n_gates}-{label}", tuple(gates), (0.0, 0.0, 0.2), 0.0)
    raise RuntimeError(f"could not draw a {n_gates}-gate track in {max_tries} tries")
