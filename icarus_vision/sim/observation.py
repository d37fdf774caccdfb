"""Observation assembly: the vector a policy sees, built from a drone state and its target gates.

Pure functions over batched arrays; ``RaceCore.observe`` picks the gates and calls them.
"""

from __future__ import annotations

import numpy as np

from icarus_vision.sim.dynamics import QuadState, quat_to_rot

OBS_DIM = 15
OBS_DIMS = {"basic": 15, "extended": 21, "racing": 25}
"""Entries of each observation layout."""


def observation_vector(
    state: QuadState,
    rpy: np.ndarray,
    gate_pos: np.ndarray,
    gate_yaw: np.ndarray,
    next_gate_pos: np.ndarray | None = None,
    gate_obs_frame: str = "world",
    gate_size: np.ndarray | None = None,
    after_yaw: np.ndarray | None = None,
) -> np.ndarray:
    """(N, 15) float32: pos, vel, rpy, body rates, next gate relative position (world or body).

    With ``next_gate_pos`` given (the extended observation), (N, 21): plus the next gate's passage
    direction and the relative position of the gate after it. With ``gate_size`` and ``after_yaw``
    also given (the racing observation), (N, 25): plus the next gate's opening side and the passage
    direction of the gate after it.

    Args:
        state: states of the N drones.
        rpy: (N, 3) roll, pitch, yaw of ``state``, radians.
        gate_pos: (N, 3) world position of each drone's target gate.
        gate_yaw: (N,) world yaw of each target gate's passage direction, radians.
        next_gate_pos: (N, 3) world position of the gate after the target, or None.
        gate_obs_frame: ``"world"``, or ``"body"`` to rotate the gate entries into the body frame.
        gate_size: (N,) side of each target gate's opening, metres (racing observation), or None.
        after_yaw: (N,) world yaw of the passage direction of the gate after the target, or None.

    Returns:
        (N, 15), (N, 21) or (N, 25) float32.
    """
    if (gate_size is None) != (after_yaw is None) or (
        gate_size is not None and next_gate_pos is None
    ):
        raise ValueError("the racing observation needs next_gate_pos, gate_size and after_yaw")
    parts = [gate_pos - state.pos]
    if next_gate_pos is not None:
        parts += [heading_vectors(gate_yaw), next_gate_pos - state.pos]
    if after_yaw is not None:
        parts.append(heading_vectors(after_yaw))
    if gate_obs_frame == "body":
        rot = quat_to_rot(state.quat)
        parts = [np.einsum("nji,nj->ni", rot, v) for v in parts]
    if gate_size is not None:
        parts.insert(3, np.asarray(gate_size, dtype=np.float64).reshape(-1, 1))
    return np.concatenate((state.pos, state.vel, rpy, state.omega, *parts), axis=1).astype(
        np.float32
    )


def heading_vectors(yaw: np.ndarray) -> np.ndarray:
    """(N, 3) horizontal unit vectors of the headings ``yaw`` (N,)."""
    return np.stack((np.cos(yaw), np.sin(yaw), np.zeros_like(yaw)), axis=1)


__all__ = ["OBS_DIM", "OBS_DIMS", "heading_vectors", "observation_vector"]
