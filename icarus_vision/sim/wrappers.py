"""Gymnasium wrappers over DroneRacingEnv observations."""

from __future__ import annotations

import gymnasium as gym
import numpy as np

from icarus_vision.sim.dynamics import quat_to_rot, rpy_to_quat

GATE_SLICE = slice(12, 15)
RPY_SLICE = slice(6, 9)


def gate_vector_to_body(obs: np.ndarray) -> np.ndarray:
    """Rotate obs[..., 12:15] (next gate relative position, world frame) into the body frame.

    Args:
        obs: (15,) or (N, 15) observations with world-frame gate vectors.

    Returns:
        Observations of the same shape with the gate vector in the body frame (FLU).
    """
    o = np.array(obs, dtype=np.float32, copy=True)
    flat = o.reshape(-1, o.shape[-1])
    rot = quat_to_rot(rpy_to_quat(flat[:, RPY_SLICE].astype(np.float64)))
    flat[:, GATE_SLICE] = np.einsum("nji,nj->ni", rot, flat[:, GATE_SLICE].astype(np.float64))
    return flat.reshape(o.shape)


class GateRelativeObsWrapper(gym.ObservationWrapper):
    """Expresses the next gate's relative position (obs[12:15]) in the drone's body frame.

    The wrapped env must produce world-frame gate vectors (``gate_obs_frame="world"``, the default).
    """

    def __init__(self, env: gym.Env) -> None:
        super().__init__(env)
        frame = getattr(env.unwrapped, "config", None)
        if frame is not None and frame.gate_obs_frame != "world":
            raise ValueError("GateRelativeObsWrapper needs an env with gate_obs_frame='world'")

    def observation(self, observation: np.ndarray) -> np.ndarray:
        return gate_vector_to_body(observation)
