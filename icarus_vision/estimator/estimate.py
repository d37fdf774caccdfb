"""What the estimator outputs: the next gate relative to the drone, and the observation slots."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from icarus_vision.sim.track import DEFAULT_GATE_SIZE

NO_GATE_DISTANCE = 5.0
"""Map-free, before any gate is seen: the estimate points this far straight ahead (m), uncertain."""
NO_GATE_SIGMA = 10.0


@dataclass(frozen=True)
class GateEstimate:
    """The next gate relative to the drone, at one time.

    Attributes:
        t: time of the odometry reading, s.
        target: passage index (map-aided) or number of gates passed so far (map-free).
        gate: index of the gate track, -1 when none (map-free before the first gate is seen).
        valid: an estimate of a real gate (False: the placeholder straight ahead).
        rel_world: (3,) gate centre minus drone position, world (odometry) frame, m.
        rel_body: (3,) the same in the body frame (FLU), m.
        cov_world: (3, 3) covariance of rel_world, m²; cov_body: (3, 3) of rel_body.
        gate_pos: (3,) gate centre, odometry world frame, m.
        yaw: heading of the passage direction, rad; yaw_sigma: its standard deviation, rad.
        measured: the next gate was updated by a detection in this call.
        since_seen_s: time since the next gate was last measured, s (inf if never).
        size: side of the next gate's opening, m (the map's, or the size PnP assumes map-free).
    """

    t: float
    target: int
    gate: int
    valid: bool
    rel_world: np.ndarray
    rel_body: np.ndarray
    cov_world: np.ndarray
    cov_body: np.ndarray
    gate_pos: np.ndarray
    yaw: float
    yaw_sigma: float
    measured: bool
    since_seen_s: float
    size: float = DEFAULT_GATE_SIZE


def fill_observation(obs: np.ndarray, estimate: GateEstimate, frame: str = "world") -> np.ndarray:
    """A copy of a (15,) or (N, 15) observation with obs[..., 12:15] from the estimate.

    Args:
        frame: the env's ``gate_obs_frame``, "world" or "body".
    """
    if frame not in ("world", "body"):
        raise ValueError(f"frame must be 'world' or 'body', got {frame!r}")
    out = np.array(obs, copy=True)
    out[..., 12:15] = estimate.rel_world if frame == "world" else estimate.rel_body
    return out
