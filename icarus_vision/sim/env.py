"""DroneRacingEnv: the Gymnasium environment, with the physics backend as the only swappable part.

``DroneRacingEnv`` owns a ``RaceCore`` (rules, reward, observation) for one drone and asks its
backend for the physics of each control step. ``BatchedDroneRacingEnv`` integrates in numpy;
``PyBulletDroneRacingEnv`` (``sim/pybullet_backend.py``) steps PyBullet.

Actions: ``[thrust, roll_rate, pitch_rate, yaw_rate]`` in [-1, 1]; finite out-of-range values are
clipped to [-1, 1]; a wrong shape or NaN/inf raises ``ValueError``.
"""

from __future__ import annotations

from abc import abstractmethod
from dataclasses import replace

import gymnasium as gym
import numpy as np

from icarus_vision.sim import dynamics
from icarus_vision.sim.config import EnvConfig
from icarus_vision.sim.dynamics import QuadState
from icarus_vision.sim.race_core import OBS_DIM, RaceCore, validate_action
from icarus_vision.sim.track import Track

OBS_BOUND = 1e4  # finite so checkers accept it; never reached


def observation_space(dim: int = OBS_DIM) -> gym.spaces.Box:
    return gym.spaces.Box(-OBS_BOUND, OBS_BOUND, shape=(dim,), dtype=np.float32)


def action_space() -> gym.spaces.Box:
    return gym.spaces.Box(-1.0, 1.0, shape=(4,), dtype=np.float32)


def make_config(cfg: EnvConfig | None = None, **overrides) -> EnvConfig:
    """An EnvConfig from an optional base plus keyword overrides (track may be a name or path)."""
    cfg = cfg or EnvConfig()
    if "track" in overrides and not isinstance(overrides["track"], Track | type(None)):
        from icarus_vision.sim.builtin import resolve_track

        overrides["track"] = resolve_track(overrides["track"])
    return replace(cfg, **overrides) if overrides else cfg


class DroneRacingEnv(gym.Env):
    """One drone racing a track. Subclasses implement the physics of one control step.

    Observation (15,) float32: position (3, world), velocity (3, world), roll/pitch/yaw (3, ZYX),
    body angular velocity (3), next gate's position relative to the drone (3, world frame unless
    ``gate_obs_frame="body"``).
    """

    metadata = {"render_modes": []}
    backend_name = "abstract"

    def __init__(self, config: EnvConfig | None = None, **overrides) -> None:
        super().__init__()
        self.config = make_config(config, **overrides)
        self.core = RaceCore(self.config, 1)
        self.observation_space = observation_space(self.config.obs_dim)
        self.action_space = action_space()
        self.state = QuadState.zeros(1)
        self._needs_reset = True

    # -- backend hooks -----------------------------------------------------------------------
    @abstractmethod
    def _backend_reset(self, state: QuadState) -> None:
        """Place the drone in ``state`` in a world built for ``self.core.tracks[0]``."""

    @abstractmethod
    def _backend_step(
        self, thrust_cmd, rate_cmd, wind
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Advance one control step; update ``self.state``.

        Returns:
            trail (S, 1, 3) sub-step positions, frame_hit (1,) bool, ground_hit (1,) bool.
        """

    # -- gymnasium API -----------------------------------------------------------------------
    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        if seed is not None:
            self.core.seed([seed])
        self.state = self.core.reset_drones(np.array([0]))
        self._backend_reset(self.state)
        self._needs_reset = False
        info = {
            "gates_passed": 0,
            "gates_total": int(self.core.n_pass[0]),
            "track": self.core.tracks[0].name,
        }
        return self.core.observe(self.state)[0], info

    def step(self, action):
        if self._needs_reset:
            raise RuntimeError("call reset() before step() (and after an episode ends)")
        a = validate_action(action, 1)
        thrust_cmd, rate_cmd = dynamics.action_to_commands(a, self.core.params)
        p0 = self.state.pos.copy()
        trail, frame_hit, ground_hit = self._backend_step(thrust_cmd, rate_cmd, self.core.wind())
        reward, term, trunc, crash, terms = self.core.finish_step(
            p0, self.state, frame_hit, ground_hit, trail, action=a
        )
        info = self.core.info(0, terms, int(crash[0]))
        self._needs_reset = bool(term[0] or trunc[0])
        obs = self.core.observe(self.state, self.core.last_rpy)[0]
        return obs, float(reward[0]), bool(term[0]), bool(trunc[0]), info

    # -- extras ------------------------------------------------------------------------------
    def set_num_gates(self, n: int) -> None:
        """Gates per episode from the next reset on (curriculum hook, reachable via env_method)."""
        self.core.set_num_gates(n)

    def set_difficulty(self, difficulty: float | None) -> None:
        """Race-layout difficulty of random tracks from the next reset on (None: classic layouts)."""
        self.core.set_difficulty(difficulty)

    @property
    def track(self) -> Track:
        """The track of the current episode."""
        return self.core.tracks[0]

    def get_state(self) -> QuadState:
        return self.state.copy()

    def set_state(self, state: QuadState) -> None:
        """Teleport the drone (tests, backend comparisons). Keeps the episode's bookkeeping."""
        self.state = state.copy()
        self._backend_reset(self.state)


class BatchedDroneRacingEnv(DroneRacingEnv):
    """The numpy backend for one drone (the same code ``BatchedRacingVecEnv`` runs for N drones)."""

    backend_name = "batched"

    def _backend_reset(self, state: QuadState) -> None:
        pass

    def _backend_step(self, thrust_cmd, rate_cmd, wind):
        return integrate_batched(self.core, self.state, thrust_cmd, rate_cmd, wind)


def integrate_batched(core: RaceCore, state: QuadState, thrust_cmd, rate_cmd, wind, accel=None):
    """Numpy physics of one control step for all drones of ``core``, with analytic collisions.

    ``accel`` (N, 3): an extra world acceleration, m/s² (``dynamics.step_substeps``).

    Returns:
        trail (S, N, 3), frame_hit (N,), ground_hit (N,).
    """
    cfg = core.cfg
    dt = 1.0 / cfg.physics_hz
    trail = dynamics.step_substeps(
        state,
        thrust_cmd,
        rate_cmd,
        wind,
        core.params,
        dt,
        cfg.substeps,
        ground_clamp=~core.taken_off,
        accel=accel,
    )
    frame_hit = core.frame_collision(trail)
    ground_hit = (trail[:, :, 2] < core.params.radius).any(axis=0)
    return trail, frame_hit, ground_hit


__all__ = [
    "DroneRacingEnv",
    "BatchedDroneRacingEnv",
    "integrate_batched",
    "observation_space",
    "action_space",
    "make_config",
]
