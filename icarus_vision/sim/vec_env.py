"""N drones in one process as a stable-baselines3 ``VecEnv`` (the training backend).

Every step is one numpy pass over all drones; finished drones reset automatically, with the last
observation in ``infos[i]["terminal_observation"]`` as SB3 expects. Drone i seeded with ``seed + i``
behaves exactly as a ``BatchedDroneRacingEnv`` reset with that seed.

Infos: by default (``info_mode="episode"``) a drone's info dict is filled only on the step its
episode ends (rules outcome, reward terms, and SB3's ``episode`` summary); other steps get an empty
dict, which keeps the step free of per-drone Python work. ``info_mode="full"`` fills every step.
The last step's per-drone arrays are always available as ``last_reward_terms`` etc.
"""

from __future__ import annotations

import time
from collections.abc import Sequence

import numpy as np
from stable_baselines3.common.vec_env.base_vec_env import VecEnv

from icarus_vision.sim import dynamics
from icarus_vision.sim.config import EnvConfig
from icarus_vision.sim.env import action_space, integrate_batched, make_config, observation_space
from icarus_vision.sim.race_core import RaceCore, validate_action


class BatchedRacingVecEnv(VecEnv):
    """``num_envs`` drones stepped together by the numpy backend."""

    def __init__(
        self,
        num_envs: int,
        config: EnvConfig | None = None,
        *,
        info_mode: str = "episode",
        **overrides,
    ) -> None:
        if num_envs < 1:
            raise ValueError(f"num_envs must be >= 1, got {num_envs}")
        if info_mode not in ("episode", "full"):
            raise ValueError(f"info_mode must be 'episode' or 'full', got {info_mode!r}")
        self.config = make_config(config, **overrides)
        self.core = RaceCore(self.config, num_envs)
        self.info_mode = info_mode
        self.render_mode = None
        super().__init__(num_envs, observation_space(self.config.obs_dim), action_space())
        self.state = dynamics.QuadState.zeros(num_envs)
        self._actions: np.ndarray | None = None
        self._seeds: list[int | None] = [None] * num_envs
        self._t0 = time.perf_counter()
        self.last_reward_terms: dict[str, np.ndarray] = {}

    # -- VecEnv API --------------------------------------------------------------------------
    def seed(self, seed: int | None = None) -> Sequence[None | int]:
        if seed is None:
            seed = int(np.random.SeedSequence().generate_state(1)[0])
        self._seeds = [seed + i for i in range(self.num_envs)]
        return list(self._seeds)

    def reset(self) -> np.ndarray:
        self.core.seed(self._seeds)
        self._seeds = [None] * self.num_envs
        self.state = self.core.reset_drones(np.arange(self.num_envs))
        self.reset_infos = [{} for _ in range(self.num_envs)]
        return self.core.observe(self.state)

    def step_async(self, actions: np.ndarray) -> None:
        self._actions = validate_action(actions, self.num_envs)

    def step_wait(self):
        core = self.core
        thrust_cmd, rate_cmd = dynamics.action_to_commands(self._actions, core.params)
        p0 = self.state.pos.copy()
        trail, frame_hit, ground_hit = integrate_batched(
            core, self.state, thrust_cmd, rate_cmd, core.wind()
        )
        reward, term, trunc, crash, terms = core.finish_step(
            p0, self.state, frame_hit, ground_hit, trail, action=self._actions
        )
        self.last_reward_terms = terms
        done = term | trunc
        if self.info_mode == "full":
            infos = [core.info(i, terms, int(crash[i])) for i in range(self.num_envs)]
        else:
            infos = [{} for _ in range(self.num_envs)]
        obs = core.observe(self.state, core.last_rpy)
        if done.any():
            idx = np.flatnonzero(done)
            for i in idx:
                info = infos[i] if infos[i] else core.info(i, terms, int(crash[i]))
                info["terminal_observation"] = obs[i].copy()
                info["TimeLimit.truncated"] = bool(trunc[i])
                info["episode"] = {
                    "r": float(core.ep_return[i]),
                    "l": int(core.ep_len[i]),
                    "t": round(time.perf_counter() - self._t0, 6),
                }
                infos[i] = info
            self.state.put(idx, core.reset_drones(idx))
            obs[idx] = core.observe(self.state)[idx]
        return obs, reward.astype(np.float32), done, infos

    def close(self) -> None:
        pass

    def get_attr(self, attr_name: str, indices=None) -> list:
        return [getattr(self, attr_name) for _ in self._get_indices(indices)]

    def set_attr(self, attr_name: str, value, indices=None) -> None:
        setattr(self, attr_name, value)

    def env_method(self, method_name: str, *method_args, indices=None, **method_kwargs) -> list:
        """Call a method for the selected drones; ``set_num_gates`` applies to the whole batch."""
        idx = list(self._get_indices(indices))
        if method_name in ("set_num_gates", "set_difficulty"):
            getattr(self.core, method_name)(*method_args, **method_kwargs)
            return [None] * len(idx)
        fn = getattr(self, method_name)
        return [fn(*method_args, **method_kwargs) for _ in idx]

    def env_is_wrapped(self, wrapper_class, indices=None) -> list[bool]:
        return [False for _ in self._get_indices(indices)]

    def set_num_gates(self, n: int) -> None:
        self.core.set_num_gates(n)

    def set_difficulty(self, difficulty: float | None) -> None:
        """Race-layout difficulty of random tracks from the next reset on (None: classic layouts)."""
        self.core.set_difficulty(difficulty)
