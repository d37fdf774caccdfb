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
    for _ in range(max_tries):
        # One batch of draws per attempt; the loop below is plain float arithmetic.
        dist = rng.uniform(*spacing, n_gates)
        turn = np.radians(rng.uniform(-max_turn_deg, max_turn_deg, n_gates))
        climb = rng.uniform(-max_climb, max_climb, n_gates)
        offset = np.radians(rng.uniform(-yaw_offset_deg, yaw_offset_deg, n_gates))
        x, y, z, heading = 0.0, 0.0, float(rng.uniform(*height)), 0.0
        placed = np.zeros((n_gates, 2))
        gates: list[Gate] = []
        for i in range(n_gates):
            direction = heading + (turn[i] if i else 0.0)
            x, y = (
                x + dist[i] * math.cos(direction),
                (y + dist[i] * math.sin(direction)) if i else 0.0,
            )
            z = min(max(z + climb[i], height[0]), height[1])
            gap = placed[:i] - (x, y)
            if (
                i and np.einsum("ij,ij->i", gap, gap).min() < min_separation**2
            ) or x * x + y * y < min_separation**2:
                break
            placed[i] = (x, y)
            heading = direction + offset[i]
            gates.append(Gate((x, y, z), math.degrees(heading), size, frame_width))
        else:
            label = seed if isinstance(seed, int) else "rng"
            return Track(f"random-{n_gates}-{label}", tuple(gates), (0.0, 0.0, 0.2), 0.0)
    raise RuntimeError(f"could not draw a {n_gates}-gate track in {max_tries} tries")
