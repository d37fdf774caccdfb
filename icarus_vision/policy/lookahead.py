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
whose own flight would crash. A clear prediction of the policy's own flight is kept, not made
again, for up to ``keep_s`` while the drone keeps to it (position, velocity, next gate and the gates
it knows, each within a tolerance) and the rest of it has room to spare; that prediction runs
``keep_s`` further ahead, so the filter still sees ``horizon_s`` ahead at every step. One
prediction then covers several control steps (measured in docs/policy.md).

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
from icarus_vision.sim import dynamics, rules
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
    keep_s: float = 0.2
    """How long a clear prediction of the policy's own flight is trusted at most, without
    predicting again, while the drone keeps to it. That prediction runs ``horizon_s + keep_s``
    ahead, so a kept one still covers ``horizon_s``. 0: predict every step (as racing mode does)."""
    keep_pos_m: float = 0.03
    """How far the drone may be from where the kept prediction put it."""
    keep_vel_mps: float = 0.15
    """How far its velocity may be from the kept prediction's."""
    keep_gate_m: float = 0.05
    """How far any gate it knows may have moved since the prediction (gates known from vision)."""
    keep_margin_m: float = 0.05
    """A prediction is kept only while the rest of its flight passes frames, ground and bounds
    with at least this much room to spare; a flight closer to a crash is predicted again."""

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
        for name in ("keep_s", "keep_pos_m", "keep_vel_mps", "keep_gate_m", "keep_margin_m"):
            if not getattr(self, name) >= 0:
                raise ValueError(f"lookahead {name} must be >= 0, got {getattr(self, name)}")


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


def _clearance(model: RaceCore, rows: np.ndarray, trails: np.ndarray) -> np.ndarray:
    """(n, T) the least room a sphere of the model's radius has at each step of ``trails``
    (n, T, S, 3) sub-step positions of the model's drones ``rows``: to any gate's frame, the
    ground and the bounds, metres (inf after a flight ended: NaN positions)."""
    n, t, sub, _ = trails.shape
    pts = trails.reshape(n, t * sub, 1, 3)
    bars = rules.gate_bar_distance(
        pts, *(a[rows][:, None] for a in (model.g_pos, model.g_yaw, model.g_size, model.g_fw))
    )
    bars = np.where(model.g_mask[rows][:, None], bars, np.inf).min(axis=2)
    p = pts[:, :, 0]
    box = np.minimum(p - model.bounds_lo[rows][:, None], model.bounds_hi[rows][:, None] - p)
    room = np.minimum(np.minimum(bars, p[..., 2]) - model.params.radius, box.min(axis=2))
    return np.nan_to_num(room, nan=np.inf).reshape(n, t, sub).min(axis=2)


_NOT_KEPT = np.iinfo(np.int64).max // 2
"""The age of a drone's plan when it has none to keep."""


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
        racing_mode = len(self.race_offsets) > 1
        self.keep_steps = 0 if racing_mode else round(self.config.keep_s * cfg.ctrl_hz)
        """Control steps a clear prediction is kept for at most (0: predict every step)."""
        self.interventions = 0
        """Drone-steps on which the filter changed the policy's action."""
        self.predictions = 0
        """Drone-steps on which the policy's own flight was predicted (the rest kept one)."""
        self._plan: dict[str, np.ndarray] | None = None  # the kept predictions (per drone)
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
            idx = idx[~self._kept(core, state, idx)]
        if idx.size:
            crash_step = self._predict_own(core, state, obs, idx)
            bad = idx[crash_step[:, 0] < self.horizon]
            if bad.size:
                crash_step, gates, ret, first, _ = self._predict(
                    core, state, obs, bad, self.offsets
                )
                score = _score(crash_step >= self.horizon, gates, ret, crash_step)
                action[bad] = first[np.arange(bad.size), score.argmax(axis=1)]
                self.interventions += int(bad.size)
        self._remember(core, state, action)
        return action

    def _race(self, core, state, obs, idx, action) -> np.ndarray:
        """Fly the race candidate that gets furthest where one stays clear with the race margin
        (writes ``action``); returns the drones where none does, for the safety filter."""
        crash_step, gates, ret, first, _ = self._predict(
            core, state, obs, idx, self.race_offsets, self.config.race_margin_m
        )
        score = _score(crash_step >= self.horizon, gates, ret, crash_step)
        best = score.argmax(axis=1)
        fine = crash_step[np.arange(idx.size), best] >= self.horizon
        moved = fine & (best != 0)
        action[idx[moved]] = first[np.flatnonzero(moved), best[moved]]
        self.interventions += int(moved.sum())
        return idx[~fine]

    # -- kept predictions ----------------------------------------------------------------------
    def _predict_own(self, core: RaceCore, state, obs, idx: np.ndarray) -> np.ndarray:
        """(len(idx), 1) crash steps of the policy's own flight; the flights that can be kept
        (also clear ``keep_s`` further) are."""
        self.predictions += int(idx.size)
        if not self.keep_steps:
            return self._predict(core, state, obs, idx, self.offsets[:1])[0]
        steps = self.horizon + self.keep_steps
        crash_step, _, _, _, path = self._predict(
            core, state, obs, idx, self.offsets[:1], steps=steps, record=True
        )
        self._keep(core, idx, crash_step[:, 0] >= steps, path)
        return crash_step

    def _kept(self, core: RaceCore, state, idx: np.ndarray) -> np.ndarray:
        """(len(idx),) bool: drones whose kept clear prediction still holds (counts a step)."""
        plan, c = self._plan, self.config
        if not self._plan_fits(core):
            return np.zeros(idx.size, dtype=bool)
        age = plan["age"][idx] + 1
        j = np.minimum(age, self.keep_steps) - 1  # the predicted step the drone is at now
        near = lambda a, b, tol: np.linalg.norm(a - b, axis=-1) <= tol  # noqa: E731  NaN: False
        ok = (
            (age <= self.keep_steps)
            & (np.abs(core.t[idx] - plan["t"][idx] - age * self.cfg.dt) < 1e-6)  # not reset
            & (core.target[idx] == plan["target"][idx, j])
            & near(state.pos[idx], plan["pos"][idx, j], c.keep_pos_m)
            & near(state.vel[idx], plan["vel"][idx, j], c.keep_vel_mps)
            & near(core.g_pos[idx], plan["gates"][idx], c.keep_gate_m).all(axis=1)
            & (plan["room"][idx, np.minimum(age, plan["room"].shape[1] - 1)] >= c.keep_margin_m)
        )
        plan["age"][idx[ok]] = age[ok]
        return ok

    def _plan_fits(self, core: RaceCore) -> bool:
        """Whether the kept plans are for a race of ``core``'s drones and gates."""
        plan = self._plan
        return plan is not None and plan["gates"].shape == core.g_pos.shape

    def _keep(self, core: RaceCore, idx: np.ndarray, clear: np.ndarray, path: dict) -> None:
        """Keep the new predictions of drones ``idx`` (only the clear ones can be kept)."""
        plan = self._plan
        if not self._plan_fits(core):
            h = self.horizon + self.keep_steps
            plan = self._plan = {
                "age": np.full(core.n, _NOT_KEPT), "t": np.zeros(core.n),
                "target": np.zeros((core.n, h), np.int64), "pos": np.zeros((core.n, h, 3)),
                "vel": np.zeros((core.n, h, 3)), "gates": np.zeros(core.g_pos.shape),
                "room": np.zeros((core.n, h)),
            }  # fmt: skip
        plan["age"][idx] = np.where(clear, 0, _NOT_KEPT)
        plan["t"][idx] = core.t[idx]
        plan["gates"][idx] = core.g_pos[idx]
        for name in ("target", "pos", "vel", "room"):
            plan[name][idx] = path[name]

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

    def _predict(self, src, state, obs, idx, offsets, extra_margin=0.0, steps=None, record=False):
        """Fly drones ``idx`` from ``state`` for ``steps`` (the horizon) once per offset.

        Returns:
            crash step (n, K) (``steps`` where none), gates passed (n, K), reward sum (n, K),
            the first actions (n, K, 4), and with ``record`` the flight of the first offset:
            ``pos``, ``vel`` (n, steps, 3) and ``target`` (n, steps) after each step (NaN and -1
            where the prediction stopped early: every flight ended), and ``room`` (n, steps): the
            least clearance from frames, ground and bounds over that step and all later ones,
            metres (None without ``record``).
        """
        steps = steps or self.horizon
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
        crash_step = np.full(model.n, steps)
        ret = np.zeros(model.n)
        first = None
        if record:
            path = {
                "pos": np.full((idx.size, steps, 3), np.nan),
                "vel": np.full((idx.size, steps, 3), np.nan),
                "target": np.full((idx.size, steps), -1, np.int64),
            }
            trails = np.full((idx.size, steps, self.cfg.substeps, 3), np.nan)
            base = np.arange(idx.size) * k
        for h in range(steps):
            a = np.asarray(self.policy.act(x), dtype=np.float32)
            if h < self.hold:
                a = np.clip(a + offset, -1.0, 1.0).astype(np.float32)
            if h == 0:
                first = a
            reward, crashed, finished, trail = self._step(model, s, a, accel)
            ret += np.where(alive, reward, 0.0)
            crash_step[alive & crashed] = h
            if record:
                path["pos"][:, h], path["vel"][:, h] = s.pos[base], s.vel[base]
                path["target"][:, h] = model.target[base]
                trails[:, h] = trail[:, base].swapaxes(0, 1)
            alive &= ~(crashed | finished)
            if not alive.any():
                break
            x = model.observe(s, model.last_rpy)
        if record:
            room = _clearance(model, base, trails)
            path["room"] = np.minimum.accumulate(room[:, ::-1], axis=1)[:, ::-1]
        shape = (idx.size, k)
        return (
            crash_step.reshape(shape),
            model.target.reshape(shape),
            ret.reshape(shape),
            first.reshape(*shape, 4),
            path if record else None,
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
        return reward, crash >= 0, model.target >= model.n_pass, trail

    # -- disturbance ---------------------------------------------------------------------------
    def _remember(self, core: RaceCore, state, action: np.ndarray) -> None:
        """Predict one step of every drone with the action flown, by the model alone (what it
        misses is the disturbance)."""
        if self.config.disturbance_gain == 0:
            return
        model = self._model(core, np.arange(core.n), 1)
        s = state.copy()
        thrust_cmd, rate_cmd = dynamics.action_to_commands(action, model.params)
        dynamics.step_substeps(s, thrust_cmd, rate_cmd, model.wind(), model.params,
                               1.0 / self.cfg.physics_hz, self.cfg.substeps,
                               ground_clamp=~model.taken_off)  # fmt: skip
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
