"""Domain randomisation drawn per episode: gate placement jitter and wind.

Each function draws from the generator it is given, in a fixed order, so a drone seeded with s
sees the same episode whichever backend or batch it runs in.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from icarus_vision.sim.track import SAME_GATE_TOL, Gate, Track

GUST_FREQ_HZ = (0.1, 1.0)


def jitter_track(track: Track, rng: np.random.Generator, pos_m: float, yaw_deg: float) -> Track:
    """Move each physical gate by a random offset (a gate flown twice moves once); z stays >= 0.8 m."""
    pos = np.array([g.pos for g in track.gates])
    close = np.linalg.norm(pos[:, None] - pos[None], axis=2) < SAME_GATE_TOL
    group = close.argmax(axis=1)  # index of the first entry of each physical gate
    dp = rng.uniform(-pos_m, pos_m, (len(pos), 3))[group]
    dyaw = rng.uniform(-yaw_deg, yaw_deg, len(pos))[group]
    new = pos + dp
    new[:, 2] = np.maximum(new[:, 2], 0.8)
    gates = tuple(
        Gate((float(p[0]), float(p[1]), float(p[2])), g.yaw_deg + float(dy), g.size, g.frame_width)
        for g, p, dy in zip(track.gates, new, dyaw, strict=True)
    )
    return replace(track, gates=gates, bounds_min=None, bounds_max=None)


def sample_wind(
    rng: np.random.Generator, wind_mps: float, gust_mps: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Draw one drone's wind: a constant horizontal part plus three sinusoidal gusts per axis.

    Args:
        rng: the drone's generator.
        wind_mps: maximum constant wind speed, m/s.
        gust_mps: maximum summed gust amplitude per axis, m/s.

    Returns:
        constant world wind (3,) m/s; gust amplitude (3, 3) m/s, frequency (3, 3) Hz and phase
        (3, 3) rad, indexed (gust, axis).
    """
    ang = rng.uniform(0, 2 * math.pi)
    const = rng.uniform(0, wind_mps) * np.array([math.cos(ang), math.sin(ang), 0.0])
    amp = rng.uniform(0, gust_mps, (3, 3)) / 3.0
    freq = rng.uniform(*GUST_FREQ_HZ, (3, 3))
    phase = rng.uniform(0, 2 * math.pi, (3, 3))
    return const, amp, freq, phase


__all__ = ["GUST_FREQ_HZ", "jitter_track", "sample_wind"]
