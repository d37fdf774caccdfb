"""Prior maps for the map-aided mode: a track's gates, possibly displaced from the real ones."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from icarus_vision.sim.track import SAME_GATE_TOL, Gate, Track


def displaced_map(
    track: Track, error_m: float = 0.0, yaw_error_deg: float = 0.0, seed: int | None = 0
) -> Track:
    """A copy of ``track`` whose physical gates are moved and turned at random (a surveyed map
    that is not quite right). A gate flown twice moves once, so its passages stay one gate.

    Args:
        error_m: standard deviation of the displacement of each gate centre, per axis, m.
        yaw_error_deg: standard deviation of the error of each gate's heading, degrees.
        seed: seed of the draws.
    """
    if not (error_m >= 0 and yaw_error_deg >= 0):
        raise ValueError(f"map errors must be >= 0, got {error_m} m, {yaw_error_deg} deg")
    rng = np.random.default_rng(seed)
    pos = np.array([g.pos for g in track.gates])
    close = np.linalg.norm(pos[:, None] - pos[None], axis=2) < SAME_GATE_TOL
    group = close.argmax(axis=1)  # first entry of each physical gate
    dp = rng.normal(0.0, error_m, (len(pos), 3))[group]
    dyaw = rng.normal(0.0, yaw_error_deg, len(pos))[group]
    gates = tuple(
        Gate(tuple(float(v) for v in p), g.yaw_deg + float(dy), g.size, g.frame_width)
        for g, p, dy in zip(track.gates, pos + dp, dyaw, strict=True)
    )
    return replace(track, gates=gates, name=f"{track.name}-map", bounds_min=None, bounds_max=None)
