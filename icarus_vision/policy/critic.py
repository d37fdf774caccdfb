"""A privileged critic: the value network reads what the simulator knows and the policy cannot.

In training the policy reads the perceived gate (perception noise, the map's error, misses) and
does not know the drone's randomised mass, thrust, drag and motor lag, the wind, the next opening's
size or how many gates are left. The value network needs none of that to act, only to judge: given
the truth it predicts a crash or a finish better, so the advantages the policy learns from are less
noisy (an asymmetric actor-critic, as in sim-to-real locomotion and racing work). Only the actor is
exported, so a policy trained this way reads and flies exactly like any other.

``PrivilegedVecEnv`` appends the privileged block to each observation the learner gets;
``AsymmetricActorCriticPolicy`` feeds the actor only the first ``actor_dim`` entries (its usual
features) and the critic all of them.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import torch
from stable_baselines3.common.policies import ActorCriticPolicy
from stable_baselines3.common.torch_layers import MlpExtractor
from stable_baselines3.common.vec_env import VecEnv, VecEnvWrapper
from torch import nn

from icarus_vision.policy.features import CLIP, _yaw_frame, obs_to_features
from icarus_vision.sim.quad import GRAVITY

EXTRA_DIM = 10
"""Privileged entries besides the true features: gates left, mass, thrust-to-weight, drag, motor
lag (ratios to the nominal, less 1), the steady wind in the heading frame (/ 5 m/s, 3), the next
opening's side (less 1 m), and the wind's gust amplitude (/ 5 m/s)."""
GATES_SCALE = 10.0
WIND_SCALE = 5.0


def privileged_dim(actor_dim: int) -> int:
    """Entries of the learner's observation: the actor's features, their true values, the extras."""
    return 2 * actor_dim + EXTRA_DIM


class PrivilegedVecEnv(VecEnvWrapper):
    """Appends the true features and the episode's hidden parameters to the learner's observation.

    Args:
        venv: the training stack's top (``FeatureVecEnv``): the actor's features; the
            ``BatchedRacingVecEnv`` at its bottom gives the drones' states, gates, randomised
            parameters and wind.
        version: the feature transform.
    """

    def __init__(self, venv: VecEnv, version: str) -> None:
        self.actor_dim = venv.observation_space.shape[0]
        dim = privileged_dim(self.actor_dim)
        space = gym.spaces.Box(-CLIP, CLIP, shape=(dim,), dtype=np.float32)
        super().__init__(venv, observation_space=space)
        self.base = venv.unwrapped
        self.core, self.version = self.base.core, version
        p = self.core.cfg.quad
        self.nominal = (p.mass, p.thrust_to_weight, float(np.mean(p.drag)), p.motor_tau)
        self.prev_extra = np.zeros((self.num_envs, EXTRA_DIM), np.float32)

    def extras(self, obs: np.ndarray) -> np.ndarray:
        """(N, EXTRA_DIM) hidden parameters of each drone's episode, scaled to order one."""
        c, params = self.core, self.core.params
        mass0, twr0, drag0, tau0 = self.nominal
        yaw = obs[:, 8]
        wind = _yaw_frame(c.wind_const, np.cos(yaw), np.sin(yaw))
        out = np.column_stack([
            (c.n_pass - c.target) / GATES_SCALE,
            params.mass / mass0 - 1,
            params.thrust_max / (params.mass * GRAVITY) / twr0 - 1,
            params.drag.mean(axis=1) / drag0 - 1,
            params.motor_tau / tau0 - 1,
            wind / WIND_SCALE,
            c.target_gate()[2] - 1.0,
            np.abs(c.gust_amp).sum(axis=(1, 2)) / WIND_SCALE,
        ])  # fmt: skip
        return np.clip(out, -CLIP, CLIP).astype(np.float32)

    def _full(self, actor: np.ndarray) -> np.ndarray:
        raw = self.core.observe(self.base.state)  # the truth, before perception noise
        extra = self.extras(raw)
        self.prev_extra = extra
        true = obs_to_features(raw, self.version)
        return np.concatenate([actor, true, extra], axis=1).astype(np.float32)

    def reset(self) -> np.ndarray:
        return self._full(self.venv.reset())

    def step_wait(self):
        prev = self.prev_extra
        obs, rew, done, infos = self.venv.step_wait()
        for i in np.flatnonzero(done):
            term = infos[i].get("terminal_observation")
            if term is not None:  # the terminal observation is the truth (no noise is applied)
                infos[i]["terminal_observation"] = np.concatenate([term, term, prev[i]])
        return self._full(obs), rew, done, infos


class SplitMlpExtractor(MlpExtractor):
    """SB3's MLP extractor whose policy network reads only the first ``actor_dim`` features."""

    def __init__(self, feature_dim: int, actor_dim: int, net_arch, activation_fn, device) -> None:
        super().__init__(feature_dim, net_arch, activation_fn, device)
        first = self.policy_net[0]
        self.policy_net[0] = nn.Linear(actor_dim, first.out_features).to(first.weight.device)
        self.actor_dim = actor_dim

    def forward(self, features: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        return self.forward_actor(features), self.forward_critic(features)

    def forward_actor(self, features: torch.Tensor) -> torch.Tensor:
        return self.policy_net(features[..., : self.actor_dim])


class AsymmetricActorCriticPolicy(ActorCriticPolicy):
    """An MlpPolicy whose actor reads the first ``actor_dim`` observation entries, its critic all."""

    def __init__(self, *args, actor_dim: int, **kwargs) -> None:
        self.actor_dim = actor_dim
        super().__init__(*args, **kwargs)

    def _build_mlp_extractor(self) -> None:
        self.mlp_extractor = SplitMlpExtractor(
            self.features_dim, self.actor_dim, self.net_arch, self.activation_fn, self.device
        )
