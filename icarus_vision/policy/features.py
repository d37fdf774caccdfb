"""The policy's fixed input transform: observation (N, 15, 21 or 25) -> features (N, F).

The policy reads the standard observation, whichever source filled it (ground truth or the
estimator). This transform makes what it reads independent of where the track lies: world x, y are
dropped, and velocity and gate vectors are turned into the drone's heading frame (rotation by −yaw,
so "ahead" is +x whatever the track's orientation). Everything is scaled to order one and clipped.
The same numpy function runs in training (``FeatureVecEnv``) and in the exported policy.

Each layout's features start with those of the smaller one (16 ⊂ 21 ⊂ 24), so a policy can be
fine-tuned on a larger observation by giving its first layer zero weights for the new features.

Version 2 (``icarus-features-v2``) appends to the extended and racing layouts the drone's place
and velocity in the next gate's own frame (along its passage direction, to its left, up) and where
the drone would cross the gate's plane flying straight on: whether it is lined up with the opening,
which version 1 gives only as a product of features (the gate vector and the passage direction)
that the network must learn to multiply. Version 1's features are the first of version 2's, so a
version 1 policy can be fine-tuned with version 2 (zero weights for the new ones); the basic
layout is the same in both. Within version 2 the extended features do not begin the racing ones
(the gate-frame features come last in each), so a version 2 policy keeps its observation.
"""

from __future__ import annotations

import numpy as np
from stable_baselines3.common.vec_env import VecEnv, VecEnvWrapper

BASIC_DIM, EXTENDED_DIM, RACING_DIM = 15, 21, 25
FEATURES_V1, FEATURES_V2 = "icarus-features-v1", "icarus-features-v2"
FEATURES_VERSION = FEATURES_V1
"""The default transform (every policy trained before version 2)."""
FEATURES_VERSIONS = {"v1": FEATURES_V1, "v2": FEATURES_V2}
"""Short names (train config ``features``) of the transforms."""
POS_SCALE, VEL_SCALE, RATE_SCALE, CLIP = 5.0, 5.0, 5.0, 5.0
NEAR_SCALE = 1.0
"""Metres per unit of the gate-frame offsets (version 2): fine near the opening."""
MAX_LOOKAHEAD_S = 2.0
"""Longest straight-on flight to the gate's plane the crossing point extrapolates (version 2)."""
GATE_FRAME_DIM = 8
SIZE_REF = 1.0
"""Opening side (m) that the racing features read as 0 (they read the side minus this)."""
_FEATURE_DIMS = {BASIC_DIM: 16, EXTENDED_DIM: 21, RACING_DIM: 24}


def feature_dim(obs_dim: int, version: str = FEATURES_V1) -> int:
    """Number of features for an observation of ``obs_dim`` (15, 21 or 25) in ``version``."""
    if obs_dim not in _FEATURE_DIMS:
        raise ValueError(f"observation must have 15, 21 or 25 entries, got {obs_dim}")
    _check_version(version)
    extra = GATE_FRAME_DIM if version == FEATURES_V2 and obs_dim >= EXTENDED_DIM else 0
    return _FEATURE_DIMS[obs_dim] + extra


def _check_version(version: str) -> None:
    if version not in FEATURES_VERSIONS.values():
        raise ValueError(
            f"unknown feature transform {version!r} (use {FEATURES_V1} or {FEATURES_V2})"
        )


def _yaw_frame(v: np.ndarray, c: np.ndarray, s: np.ndarray) -> np.ndarray:
    """Rotate world vectors (N, 3) by −yaw about z."""
    out = np.empty((len(v), 3))
    x, y = v[:, 0], v[:, 1]
    out[:, 0] = c * x + s * y
    out[:, 1] = -s * x + c * y
    out[:, 2] = v[:, 2]
    return out


def obs_to_features(obs: np.ndarray, version: str = FEATURES_V1) -> np.ndarray:
    """Features of world-frame observations.

    Args:
        obs: (N, 15), (N, 21) or (N, 25) observations with world-frame gate vectors.
        version: ``FEATURES_V1`` or ``FEATURES_V2`` (adds ``gate_frame_features`` to the extended
            and racing layouts, after version 1's).

    Returns:
        (N, 16), (N, 21) or (N, 24) float32: altitude, velocity (heading frame), roll, pitch, body
        rates, next gate vector (heading frame), its distance, its unit direction; extended adds the
        gate's passage direction (heading frame, x, y) and the following gate's vector (heading
        frame); racing adds the gate's opening side (minus ``SIZE_REF``) and the following gate's
        passage direction (heading frame, x, y).
    """
    obs = np.asarray(obs, dtype=np.float64)
    if obs.ndim != 2:
        raise ValueError(f"obs must be (N, 15), (N, 21) or (N, 25), got shape {obs.shape}")
    out = np.empty((len(obs), feature_dim(obs.shape[1], version)))  # filled column by column
    yaw = obs[:, 8]
    c, s = np.cos(yaw), np.sin(yaw)
    out[:, 0] = obs[:, 2] / POS_SCALE
    out[:, 1:4] = _yaw_frame(obs[:, 3:6], c, s) / VEL_SCALE
    out[:, 4:6] = obs[:, 6:8]
    out[:, 6:9] = obs[:, 9:12] / RATE_SCALE
    gate = _yaw_frame(obs[:, 12:15], c, s)
    dist = np.linalg.norm(gate, axis=1, keepdims=True)
    out[:, 9:12] = gate / POS_SCALE
    out[:, 12:13] = dist / POS_SCALE
    out[:, 13:16] = gate / np.maximum(dist, 1e-3)
    k = 16
    if obs.shape[1] >= EXTENDED_DIM:
        out[:, 16:18] = _yaw_frame(obs[:, 15:18], c, s)[:, :2]
        out[:, 18:21] = _yaw_frame(obs[:, 18:21], c, s) / POS_SCALE
        k = 21
    if obs.shape[1] == RACING_DIM:
        out[:, 21] = obs[:, 21] - SIZE_REF
        out[:, 22:24] = _yaw_frame(obs[:, 22:25], c, s)[:, :2]
        k = 24
    if version == FEATURES_V2 and obs.shape[1] >= EXTENDED_DIM:
        out[:, k:] = gate_frame_features(obs)
    return np.clip(out, -CLIP, CLIP, out=out).astype(np.float32)


def passage_heading(obs: np.ndarray) -> np.ndarray:
    """(N, 2) unit horizontal passage direction of the next gate (extended or racing observations)."""
    return obs[:, 15:17] / np.maximum(np.linalg.norm(obs[:, 15:17], axis=1, keepdims=True), 1e-9)


def gate_frame_features(obs: np.ndarray) -> np.ndarray:
    """(N, 8) the drone in the next gate's frame (extended or racing observations).

    Position (along the passage direction, negative before the gate, / ``POS_SCALE``; left and up
    / ``NEAR_SCALE``), velocity (/ ``VEL_SCALE``) and the crossing point's left and up offsets
    (/ ``NEAR_SCALE``) if the drone flew on straight at its velocity (at most ``MAX_LOOKAHEAD_S``,
    at least 1 m/s toward the plane; its offsets now once past the plane).
    """
    heading = passage_heading(obs)
    c, s = heading[:, 0], heading[:, 1]
    local = _yaw_frame(-obs[:, 12:15], c, s)
    vel = _yaw_frame(obs[:, 3:6], c, s)
    t = np.minimum(np.maximum(-local[:, 0], 0.0) / np.maximum(vel[:, 0], 1.0), MAX_LOOKAHEAD_S)
    cross = local[:, 1:] + vel[:, 1:] * t[:, None]
    return np.concatenate(
        (local[:, :1] / POS_SCALE, local[:, 1:] / NEAR_SCALE, vel / VEL_SCALE, cross / NEAR_SCALE),
        axis=1,
    )


def policy_input(obs: np.ndarray, version: str = FEATURES_V1, reference=None) -> np.ndarray:
    """What the policy network reads: ``obs_to_features`` of ``version``, followed by the plan
    features of ``reference`` (a ``reference.PlanReference``) when there is one."""
    out = obs_to_features(obs, version)
    if reference is None:
        return out
    return np.concatenate((out, reference.features(obs)), axis=1)


class FeatureVecEnv(VecEnvWrapper):
    """Feeds ``policy_input`` (of ``version`` and ``reference``) of the wrapped VecEnv's
    observations to the learner."""

    def __init__(self, venv: VecEnv, version: str = FEATURES_V1, reference=None) -> None:
        import gymnasium as gym

        self.version, self.reference = version, reference
        dim = feature_dim(venv.observation_space.shape[0], version)
        dim += 0 if reference is None else reference.dim
        space = gym.spaces.Box(-CLIP, CLIP, shape=(dim,), dtype=np.float32)
        super().__init__(venv, observation_space=space)

    def _input(self, obs: np.ndarray) -> np.ndarray:
        return policy_input(obs, self.version, self.reference)

    def reset(self) -> np.ndarray:
        return self._input(self.venv.reset())

    def step_wait(self):
        obs, rew, done, infos = self.venv.step_wait()
        for i in np.flatnonzero(done):
            if "terminal_observation" in infos[i]:
                infos[i]["terminal_observation"] = self._input(
                    infos[i]["terminal_observation"][None]
                )[0]
        return self._input(obs), rew, done, infos
