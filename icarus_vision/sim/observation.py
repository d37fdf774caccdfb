"""Observation assembly: the vector a policy sees, built from a drone state and its target gates.

Pure functions over batched arrays; ``RaceCore.observe`` picks the gates and calls them.
"""

from __future__ import annotations

import numpy as np

from icarus_vision.sim.dynamics import QuadState, quat_to_rot

OBS_DIM = 15


def observation_vector(
    state: QuadState,
    rpy: np.ndarray,
    gate_pos: np.ndarray,
    gate_yaw: np.ndarray,
    next_gate_pos: np.ndarray | None = None,
    gate_obs_frame: str = "world",
) -> np.ndarray:
    """(N, 15) float32: pos, vel, rpy, body rates, next gate relative position (world or body).

    With ``next_gate_pos`` given (the extended observation), (N, 21): plus the next gate's passage
    direction and the relative position of the gate after it.

    Args:
        state: states of the N drones.
        rpy: (N, 3) roll, pitch, yaw of ``state``, radians.
        gate_pos: (N, 3) world position of each drone's target gate.
        gate_yaw: (N,) world yaw of each target gate's passage direction, radians.
        next_gate_pos: (N, 3) world position of the gate after the target, or None.
        gate_obs_frame: ``"world"``, or ``"body"`` to rotate the gate entries into the body frame.

    Returns:
        (N, 15) or (N, 21) float32.
    """
    parts = [gate_pos - state.pos]
    if next_gate_pos is not None:
        normal = np.stack((np.cos(gate_yaw), np.sin(gate_yaw), np.zeros_like(gate_yaw)), axis=1)
        parts += [normal, next_gate_pos - state.pos]
    if gate_obs_frame == "body":
        rot = quat_to_rot(state.quat)
        parts = [np.einsum("nji,nj->ni", rot, v) for v in parts]
    return np.concatenate((state.pos, state.vel, rpy, state.omega, *parts), axis=1).astype(
        np.float32
    )


__all__ = ["OBS_DIM", "observation_vector"]
