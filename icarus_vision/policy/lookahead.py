"""A safety filter around a policy: a short look-ahead in the quadrotor's own model.

Every control step the filter predicts the next ``horizon_s`` of flight in the batched numpy model
of the quadrotor, with the policy flying it. When that flight hits a gate, the ground or the
bounds, it predicts the same for candidate actions — the policy's action plus an offset on one
axis (collective thrust or one body rate), held for ``offset_s``, the policy flying on after it —
and flies the first action of the candidate that stays clear and gets furthest. When the policy's
own flight stays clear (nearly always) its action is flown unchanged, so the filter costs no
lap time where nothing goes wrong.

The model is the nominal quadrotor: the filter does not know the randomised mass, thrust or the
wind. What the model misses shows each step as the measured velocity against the predicted one;
that difference, low-pass filtered, is added to every prediction as a world acceleration.

Predictions of all drones and all candidates run as one batch; the candidates only for the drones
whose own flight would crash.

In its racing mode (``racing()``, `--lookahead-race`) the filter also improves on a flight that
stays clear: it tries the policy's action with the pitch rate offset by ±0.25 and ±0.5 for 0.2 s and
flies the candidate that passes the most gates and earns the most reward over the horizon, where
that candidate keeps ``race_margin_m`` more from frames and ground than the policy's own flight
must. A rollout of the policy is the base, so the choice is never worse than the policy's own
within the horizon; the margin keeps the faster flight from ending at the edge of what the model
can still correct.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from icarus_vision.policy.export import ExportedPolicy
from icarus_vision.sim import dynamics
from icarus_vision.sim.config import EnvConfig, RandomizationConfig
from icarus_vision.sim.env import integrate_batched
from icarus_vision.sim.race_core import RaceCore


@dataclass(frozen=True)
class LookaheadConfig:
    """How far and how widely the filter looks."""

    horizon_s: float = 0.6
    """Seconds of flight predicted each control step."""
    offset_s: float = 0.2
    """How long a candidate's offset is held before the policy flies on alone."""
    amplitudes: tuple[float, ...] = (0.25, 0.5, 1.0, 1.5, 2.0)
    """Offsets tried on each action axis, both signs (action units; actions stay in [-1, 1])."""
    disturbance_gain: float = 0.2
    """Low-pass gain per control step of the disturbance estimate (0: none estimated)."""
    margin_m: float = 0.0
    """Added to the drone's radius in the model: a flight that passes closer than this to a gate's
    frame or the ground counts as a crash (room for the error of gates known from vision)."""
    race_amplitudes: tuple[float, ...] = ()
    """Offsets tried on each axis, both signs, also when the policy's own flight stays clear; the
    filter then flies the clear candidate that passes most gates and earns the most reward over
    the horizon (policy improvement by rollout: never worse than the policy's own flight within
    the horizon, and slower to compute). Empty: the policy's action is flown whenever it is
    clear."""
    race_axes: tuple[int, ...] = (0, 1, 2, 3)
    """The action axes ``race_amplitudes`` are tried on (0 thrust, 1–3 roll, pitch, yaw rate)."""
    race_margin_m: float = 0.3
    """A candidate other than the policy's own action is flown for speed only when its flight
    keeps this much more from frames and ground than ``margin_m``."""

    def __post_init__(self) -> None:
        if not self.horizon_s > 0:
            raise ValueError(f"lookahead horizon_s must be > 0, got {self.horizon_s}")
        if not 0 < self.offset_s <= self.horizon_s:
            raise ValueError(f"lookahead offset_s must be in (0, horizon_s], got {self.offset_s}")
        if not self.amplitudes or any(not 0 < a <= 2 for a in self.amplitudes):
            raise ValueError(f"lookahead amplitudes must be in (0, 2], got {self.amplitudes}")
        if not 0 <= self.disturbance_gain <= 1:
            raise ValueError(f"disturbance_gain must be in [0, 1], got {self.disturbance_gain}")
        if not 0 <= self.margin_m < 1:
            raise ValueError(f"lookahead margin_m must be in [0, 1), got {self.margin_m}")
        if any(not 0 < a <= 2 for a in self.race_amplitudes):
            raise ValueError(
                f"lookahead race_amplitudes must be in (0, 2], got {self.race_amplitudes}"
            )
        if not self.race_axes or any(a not in (0, 1, 2, 3) for a in self.race_axes):
            raise ValueError(f"lookahead race_axes must be action axes 0–3, got {self.race_axes}")


def racing(margin_m: float = 0.0) -> LookaheadConfig:
    """The filter's racing mode (measured in docs/history/policy.md, 2026-12-07): pitch-rate
    offsets of ±0.25 and ±0.5 tried every step, flown when clear by 0.3 m more."""
    return LookaheadConfig(margin_m=margin_m, race_amplitudes=(0.25, 0.5), race_axes=(2,))


def as_config(lookahead: bool | LookaheadConfig) -> LookaheadConfig | None:
    """The filter a caller asked for: None for False, the default settings for True, a
    ``LookaheadConfig`` as given; anything else is refused."""
    if not isinstance(lookahead, (bool, LookaheadConfig)):
        raise ValueError(f"lookahead must be a bool or a LookaheadConfig, got {lookahead!r}")
    return LookaheadConfig() if lookahead is True else lookahead or None


def candidate_offsets(
    amplitudes: tuple[float, ...], axes: tuple[int, ...] = (0, 1, 2, 3)
) -> np.ndarray:
    """(K, 4) action offsets: none first, then ± each amplitude on each of ``axes`` alone."""
    out = [np.zeros(4)]
    for axis in axes:
        for amp in amplitudes:
            for sign in (1.0, -1.0):
                o = np.zeros(4)
                o[axis] = sign * amp
                out.append(o)
    return np.array(out)


def _score(clear, gates, ret, crash_step) -> np.ndarray:
    """(n, K) candidate ranking: clear flights first, by gates passed then reward; the others by
    how late they crash."""
    return np.where(clear, 1e9 + 1e4 * gates + ret, crash_step.astype(float))


class Lookahead:
    """A policy with a look-ahead safety filter (``act`` as a pilot of N drones).

    Args:
        policy: the exported policy flown (and flying every prediction).
        cfg: the race's configuration; the model flies its quadrotor without randomisation.
    """

    def __init__(
        self, policy: ExportedPolicy, cfg: EnvConfig, config: LookaheadConfig | None = None
    ) -> None:
        self.policy = policy
        self.config = config or LookaheadConfig()
        self.cfg = replace(
            cfg,
            randomization=RandomizationConfig(enabled=False),
            layout_replay=0.0,
            crash_replay=0.0,
        )
        self.horizon = max(1, round(self.config.horizon_s * cfg.ctrl_hz))
        self.hold = max(1, min(self.horizon, round(self.config.offset_s * cfg.ctrl_hz)))
        self.offsets = candidate_offsets(self.config.amplitudes)
        self.race_offsets = (
            candidate_offsets(self.config.race_amplitudes, self.config.race_axes)
            if self.config.race_amplitudes
            else self.offsets[:1]
        )
        self.interventions = 0
        """Drone-steps on which the filter changed the policy's action."""
        self._models: dict[tuple[int, float], RaceCore] = {}
        self._accel: np.ndarray | None = None  # (N, 3) disturbance estimate, m/s²
        self._pred_vel: np.ndarray | None = None  # (N, 3) velocity the model predicted
        self._t: np.ndarray | None = None  # race clock at the last act (a drone reset since
        # then starts its disturbance estimate afresh)

    def act(
        self,
        core: RaceCore,
        state: dynamics.QuadState,
        obs: np.ndarray,
        live: np.ndarray | None = None,
    ) -> np.ndarray:
        """Actions for the drones of ``core``.

        Args:
            core: the race as the pilot knows it: gates, next-gate indices, clocks (N drones).
            state: the drones' states (N).
            obs: (N, obs_dim) their observations.
            live: (N,) bool, drones still racing (None: all); the others fly the policy unfiltered.

        Returns:
            (N, 4) float32 actions in [-1, 1].
        """
        self._update_disturbance(core, state)
        action = np.asarray(self.policy.act(obs), dtype=np.float32).copy()
        idx = np.arange(core.n) if live is None else np.flatnonzero(live)
        if idx.size and len(self.race_offsets) > 1:
            idx = self._race(core, state, obs, idx, action)
        if idx.size:
            crash_step = self._predict(core, state, obs, idx, self.offsets[:1])[0][:, 0]
            bad = idx[crash_step < self.horizon]
            if bad.size:
                crash_step, gates, ret, first = self._predict(core, state, obs, bad, self.offsets)
                score = _score(crash_step >= self.horizon, gates, ret, crash_step)
                action[bad] = first[np.arange(bad.size), score.argmax(axis=1)]
                self.interventions += int(bad.size)
        self._remember(core, state, action)
        return action

    def _race(self, core, state, obs, idx, action) -> np.ndarray:
        """Fly the race candidate that gets furthest where one stays clear with the race margin
        (writes ``action``); returns the drones where none does, for the safety filter."""
        crash_step, gates, ret, first = self._predict(
            core, state, obs, idx, self.race_offsets, self.config.race_margin_m
        )
        score = _score(crash_step >= self.horizon, gates, ret, crash_step)
        best = score.argmax(axis=1)
        fine = crash_step[np.arange(idx.size), best] >= self.horizon
        moved = fine & (best != 0)
        action[idx[moved]] = first[np.flatnonzero(moved), best[moved]]
        self.interventions += int(moved.sum())
        return idx[~fine]

    # -- the model -----------------------------------------------------------------------------
    def _model(
        self, src: RaceCore, idx: np.ndarray, repeats: int, extra_margin: float = 0.0
    ) -> RaceCore:
        """A model core whose drones are ``src``'s drones ``idx``, each ``repeats`` times, its
        radius grown by ``margin_m`` + ``extra_margin``."""
        m = idx.size * repeats
        model = self._models.get((m, extra_margin))
        if model is None:
            model = RaceCore(replace(self.cfg, track=src.cfg.track), m)
            model.params.radius = model.params.radius + self.config.margin_m + extra_margin
            self._models[(m, extra_margin)] = model
        n = src.n
        for name, val in vars(src).items():
            if isinstance(val, np.ndarray) and val.ndim >= 1 and val.shape[0] == n:
                if name not in ("wind_const", "gust_amp", "gust_freq", "gust_phase"):
                    setattr(model, name, np.repeat(val[idx], repeats, axis=0))
        model.n, model.cap = m, src.cap
        model.ep_terms = {}
        model.lap_times = [[] for _ in range(m)]
        model.wind_const = np.zeros((m, 3))
        model.gust_amp = np.zeros((m, 3, 3))
        return model

    def _predict(self, src, state, obs, idx, offsets, extra_margin=0.0):
        """Fly drones ``idx`` from ``state`` for the horizon once per offset.

        Returns:
            crash step (n, K) (the horizon where none), gates passed (n, K), reward sum (n, K),
            and the first actions (n, K, 4).
        """
        k = len(offsets)
        model = self._model(src, idx, k, extra_margin)
        rep = lambda a: np.repeat(a[idx], k, axis=0)  # noqa: E731
        s = dynamics.QuadState(
            *(rep(a) for a in (state.pos, state.vel, state.quat, state.omega, state.thrust))
        )
        accel = None if self._accel is None else rep(self._accel)
        offset = np.tile(offsets, (idx.size, 1))
        x = np.repeat(obs[idx], k, axis=0)
        alive = np.ones(model.n, dtype=bool)
        crash_step = np.full(model.n, self.horizon)
        ret = np.zeros(model.n)
        first = None
        for h in range(self.horizon):
            a = np.asarray(self.policy.act(x), dtype=np.float32)
            if h < self.hold:
                a = np.clip(a + offset, -1.0, 1.0).astype(np.float32)
            if h == 0:
                first = a
            reward, crashed, finished = self._step(model, s, a, accel)
            ret += np.where(alive, reward, 0.0)
            crash_step[alive & crashed] = h
            alive &= ~(crashed | finished)
            if not alive.any():
                break
            x = model.observe(s, model.last_rpy)
        shape = (idx.size, k)
        return (
            crash_step.reshape(shape),
            model.target.reshape(shape),
            ret.reshape(shape),
            first.reshape(*shape, 4),
        )

    @staticmethod
    def _step(model: RaceCore, state, action, accel):
        thrust_cmd, rate_cmd = dynamics.action_to_commands(action, model.params)
        p0 = state.pos.copy()
        trail, frame_hit, ground_hit = integrate_batched(
            model, state, thrust_cmd, rate_cmd, model.wind(), accel
        )
        reward, _, _, crash, _ = model.finish_step(
            p0, state, frame_hit, ground_hit, trail, action=action
        )
        return reward, crash >= 0, model.target >= model.n_pass

    # -- disturbance ---------------------------------------------------------------------------
    def _remember(self, core: RaceCore, state, action: np.ndarray) -> None:
        """Predict one step of every drone with the action flown, by the model alone (what it
        misses is the disturbance)."""
        if self.config.disturbance_gain == 0:
            return
        idx = np.arange(core.n)
        model = self._model(core, idx, 1)
        s = state.copy()
        self._step(model, s, action, None)
        self._pred_vel = s.vel
        self._t = core.t.copy()

    def _update_disturbance(self, core: RaceCore, state) -> None:
        if self._pred_vel is None or self._pred_vel.shape[0] != core.n:
            self._accel = np.zeros((core.n, 3))
            return
        dt = self.cfg.dt
        went_on = np.abs(core.t - (self._t + dt)) < 1e-6  # not reset since the last step
        miss = (state.vel - self._pred_vel) / dt
        gain = self.config.disturbance_gain
        self._accel = np.where(went_on[:, None], self._accel + gain * (miss - self._accel), 0.0)


__all__ = ["Lookahead", "LookaheadConfig", "as_config", "candidate_offsets", "racing"]
