"""Backend-independent race logic for N drones: episodes, randomisation, rules, reward, observation.

A backend only integrates the physics and reports collisions; everything a race *means* lives here,
once, so the batched numpy backend and the PyBullet backend cannot disagree on it.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from icarus_vision.sim import rules
from icarus_vision.sim.action import validate_action
from icarus_vision.sim.builtin import resolve_track
from icarus_vision.sim.config import EnvConfig
from icarus_vision.sim.dynamics import (
    QuadBatchParams,
    QuadState,
    quat_to_rot,
    quat_to_rpy,
    rpy_to_quat,
)
from icarus_vision.sim.observation import OBS_DIM, observation_vector
from icarus_vision.sim.race_layouts import race_track
from icarus_vision.sim.random_track import random_track
from icarus_vision.sim.randomization import jitter_track, sample_wind
from icarus_vision.sim.reward import (
    camera_gate_angle,
    compute_reward,
    cost_action_change,
    reward_line,
    reward_path,
)
from icarus_vision.sim.track import Track

TAKEOFF_CLEARANCE = 0.1  # m above the ground (sphere bottom) that counts as airborne
RANDOM_TRACK_GATES = 10
REPLAY_CAPACITY = 1024  # failed layouts kept for ``layout_replay``, newest kept
SNAPSHOT_S = 0.2  # crash replay: a snapshot of each drone's flight every this many seconds
SNAPSHOT_SLOTS = 10  # ... the last ten kept (2 s)
PLAN_START_CLEARANCE_M = 0.5  # plan starts: a node's least distance from the gates either side
_SNAP_STATE = ("pos", "vel", "quat", "omega", "thrust")


class RaceCore:
    """Race bookkeeping for N drones. Backends call ``reset_drones``, ``wind``, ``finish_step``.

    Per-drone randomness comes from per-drone generators, so drone i of a batch seeded with s
    behaves exactly as a single-drone env seeded with s + i.
    """

    def __init__(self, cfg: EnvConfig, n: int) -> None:
        self.cfg = cfg
        self.n = n
        self.base_track = None if cfg.random_tracks else resolve_track(cfg.track)
        self.num_gates = cfg.num_gates
        self.difficulty = cfg.layout_difficulty
        self.rngs = [np.random.default_rng() for _ in range(n)]
        self.tracks: list[Track] = [None] * n  # type: ignore[list-item]
        self.layouts: list[Track] = [None] * n  # type: ignore[list-item]  # before the jitter
        self.replay: list[Track] = []  # layouts failed on, for ``cfg.layout_replay``
        self.replayed = np.zeros(n, dtype=bool)
        self.params = QuadBatchParams.from_quad(cfg.quad, n)
        self._alloc(self._capacity())
        self.target = np.zeros(n, dtype=np.int64)
        self.t = np.zeros(n)
        self.max_t = np.zeros(n)
        self.taken_off = np.zeros(n, dtype=bool)
        self.lap_start = np.zeros(n)
        self.last_lap_time = np.full(n, np.nan)
        self.finish_t = np.full(n, np.nan)  # when the last passage was made (NaN until then)
        self.gates_per_lap = np.ones(n, dtype=np.int64)
        self.wind_const = np.zeros((n, 3))
        self.gust_amp = np.zeros((n, 3, 3))
        self.gust_freq = np.zeros((n, 3, 3))
        self.gust_phase = np.zeros((n, 3, 3))
        self.ep_return = np.zeros(n)
        self.ep_terms: dict[str, np.ndarray] = {}  # per-term episode sums
        self.ep_len = np.zeros(n, dtype=np.int64)
        self.lap_times: list[list[float]] = [[] for _ in range(n)]
        self.n_laps = np.zeros(n, dtype=np.int64)  # len(lap_times[i]), as an array
        self.start_pos = np.zeros((n, 3))
        self.ep_difficulty = np.full(n, np.nan)  # layout difficulty of each drone's episode
        self.prev_action = np.full((n, 4), np.nan)
        self.crashes: list[dict] = []  # moments before crashes, for ``cfg.crash_replay``
        self.ref_path: np.ndarray | None = None  # (P, M + 1, 3): ``set_reference``
        self.ref_arc: np.ndarray | None = None  # (P, M + 1) arc length along each
        self.plan_nodes: dict[str, np.ndarray] | None = None  # ``set_plan``: start states
        self._snap_every = max(1, round(SNAPSHOT_S * cfg.ctrl_hz))
        if cfg.crash_replay > 0:
            self.snaps = {
                "pos": np.zeros((n, SNAPSHOT_SLOTS, 3)), "vel": np.zeros((n, SNAPSHOT_SLOTS, 3)),
                "quat": np.zeros((n, SNAPSHOT_SLOTS, 4)), "omega": np.zeros((n, SNAPSHOT_SLOTS, 3)),
                "thrust": np.zeros((n, SNAPSHOT_SLOTS)), "prev_action": np.zeros((n, SNAPSHOT_SLOTS, 4)),
                "t": np.full((n, SNAPSHOT_SLOTS), np.nan), "lap_start": np.zeros((n, SNAPSHOT_SLOTS)),
                "target": np.zeros((n, SNAPSHOT_SLOTS), dtype=np.int64),
                "laps": np.zeros((n, SNAPSHOT_SLOTS), dtype=np.int64),
            }  # fmt: skip

    # -- track arrays ------------------------------------------------------------------------
    def _capacity(self) -> int:
        if self.base_track is None:
            return self.num_gates or RANDOM_TRACK_GATES
        return self.base_track.num_passages

    def _alloc(self, cap: int) -> None:
        n = self.n
        self.cap = cap
        self.g_pos = np.zeros((n, cap, 3))
        self.g_pos[:, :, 2] = -1e3  # padding far below the world
        self.g_yaw = np.zeros((n, cap))
        self.g_reach = np.zeros((n, cap))  # centre-to-outer-corner distance of each gate
        self.g_cos = np.ones((n, cap))
        self.g_sin = np.zeros((n, cap))
        self.g_size = np.ones((n, cap))
        self.g_fw = np.full((n, cap), 0.1)
        self.g_mask = np.zeros((n, cap), dtype=bool)
        self.n_pass = np.ones(n, dtype=np.int64)
        self.bounds_lo = np.zeros((n, 3))
        self.bounds_hi = np.zeros((n, 3))

    def set_num_gates(self, n_gates: int) -> None:
        """Gates per episode from the next reset on (curriculum hook)."""
        if n_gates < 1:
            raise ValueError(f"num gates must be >= 1, got {n_gates}")
        if self.base_track is not None and n_gates > len(self.base_track.gates):
            n_gates = len(self.base_track.gates)
        if int(n_gates) != self.num_gates:
            self.replay.clear()  # the failed layouts have the old gate count
        self.num_gates = int(n_gates)
        need = n_gates if self.base_track is None else n_gates * self.base_track.laps
        if need > self.cap:
            names = ("g_pos", "g_yaw", "g_reach", "g_cos", "g_sin", "g_size", "g_fw", "g_mask")
            old = {k: getattr(self, k) for k in (*names, "n_pass", "bounds_lo", "bounds_hi")}
            c = self.cap
            self._alloc(need)
            for k in names:
                getattr(self, k)[:, :c] = old[k]
            for k in ("n_pass", "bounds_lo", "bounds_hi"):
                setattr(self, k, old[k])

    def set_reference(self, paths: list[np.ndarray]) -> None:
        """The reference path of each passage for the ``path`` reward term: ``paths[k]`` (M_k + 1, 3)
        runs from passage k − 1 (or the start) to passage k of the fixed track, e.g. the
        time-optimal plan's nodes between them (``PlanResult.passage_paths``). Every drone flies
        against the same reference; randomisation moves the gates, not it."""
        if self.base_track is None:
            raise ValueError("a reference path needs a fixed track (random tracks have none)")
        if len(paths) != self.base_track.num_passages:
            raise ValueError(
                f"reference: {len(paths)} paths for {self.base_track.num_passages} passages"
            )
        paths = [np.asarray(q, dtype=np.float64) for q in paths]
        if any(q.ndim != 2 or q.shape[1] != 3 or len(q) < 2 for q in paths):
            raise ValueError("reference: each path needs two or more (x, y, z) points")
        if not all(np.all(np.isfinite(q)) for q in paths):
            raise ValueError("reference: paths must be finite")
        m = max(len(q) for q in paths)
        ref = np.stack([np.concatenate([q, np.repeat(q[-1:], m - len(q), axis=0)]) for q in paths])
        self.ref_path = ref  # (P, M + 1, 3), padded with each path's last point
        steps = np.linalg.norm(np.diff(ref, axis=1), axis=2)
        self.ref_arc = np.concatenate([np.zeros((len(ref), 1)), np.cumsum(steps, axis=1)], axis=1)

    def set_plan(self, plan, clearance_m: float = PLAN_START_CLEARANCE_M) -> None:
        """The time-optimal plan of the fixed track (a ``planning.PlanResult``) that
        ``cfg.plan_start`` episodes start from: any node between two passages whose position
        keeps ``clearance_m`` from the centres of the gates on either side (so that the gates'
        jitter neither puts a start behind its target's plane nor inside the gate just passed)."""
        if self.base_track is None:
            raise ValueError("plan starts need a fixed track (random tracks have none)")
        gate_nodes = np.asarray(plan.gate_nodes, dtype=np.int64)
        if len(gate_nodes) != self.base_track.num_passages:
            raise ValueError(
                f"plan: {len(gate_nodes)} passages for {self.base_track.num_passages} on the track"
            )
        attr_of = {"t": "t", "pos": "pos", "vel": "vel", "quat": "quat", "omega": "rates",
                   "thrust": "thrust"}  # fmt: skip  # start state <- plan attribute
        nodes = {n: np.asarray(getattr(plan, a), dtype=np.float64) for n, a in attr_of.items()}
        k = np.arange(len(nodes["t"]))
        target = np.searchsorted(gate_nodes, k, side="left")  # passages at nodes before k
        inner = (k > 0) & (target < len(gate_nodes)) & ~np.isin(k, gate_nodes)
        centres = np.array([g.pos for g in self.base_track.passages])
        pos = nodes["pos"]
        ahead = np.linalg.norm(pos - centres[np.minimum(target, len(centres) - 1)], axis=1)
        behind = np.where(
            target > 0, np.linalg.norm(pos - centres[np.maximum(target - 1, 0)], axis=1), np.inf
        )
        ok = inner & (ahead >= clearance_m) & (behind >= clearance_m)
        if not ok.any():
            raise ValueError(f"plan: no node keeps {clearance_m} m from the gates")
        self.plan_nodes = {n: v[ok] for n, v in nodes.items()}
        self.plan_nodes["target"] = target[ok]
        self.plan_nodes["crossed"] = nodes["t"][gate_nodes]

    def _plan_node(self, rng: np.random.Generator, passages: int) -> int | None:
        """A plan node to start from, or None (``cfg.plan_start``; nothing drawn when it is 0).
        ``passages``: the episode's; a track cut short by the curriculum starts from the start."""
        if self.cfg.plan_start <= 0:
            return None
        if self.plan_nodes is None:
            raise RuntimeError("plan_start needs the track's plan: RaceCore.set_plan")
        if rng.random() >= self.cfg.plan_start or passages != len(self.plan_nodes["crossed"]):
            return None
        return int(rng.integers(len(self.plan_nodes["t"])))

    def _start_from_plan(self, k: int, i: int, node: int, state: QuadState) -> None:
        """Drone ``i`` (row ``k`` of ``state``) starts at plan node ``node``: the plan's state, its
        thrust scaled to this drone's mass (the plan's acceleration), its clock and laps."""
        m = self.plan_nodes
        for name in ("pos", "vel", "quat", "omega"):
            getattr(state, name)[k] = m[name][node]
        p = self.params
        state.thrust[k] = min(m["thrust"][node] * p.mass[i] / self.cfg.quad.mass, p.thrust_max[i])
        j = int(m["target"][node])
        self.target[i], self.t[i] = j, m["t"][node]
        laps = j // self.gates_per_lap[i]
        ends = m["crossed"][self.gates_per_lap[i] - 1 :: self.gates_per_lap[i]][:laps]
        self.lap_start[i] = ends[-1] if laps else 0.0
        self._resume(i, np.diff(np.concatenate([[0.0], ends])).tolist())

    def set_difficulty(self, difficulty: float | None) -> None:
        """Race-layout difficulty of random tracks from the next reset on (curriculum hook).

        None draws the classic ``random_track`` layouts; a value in [0, 1] draws ``race_track``.
        """
        if difficulty is not None and not 0.0 <= difficulty <= 1.0:
            raise ValueError(f"layout difficulty must be in [0, 1] or None, got {difficulty}")
        if difficulty != self.difficulty:
            self.replay.clear()
        self.difficulty = difficulty

    def _replay_layout(self, rng: np.random.Generator) -> Track | None:
        """A failed layout to fly again, or None (the buffer fills only with ``layout_replay``
        on random tracks: ``finish_step``)."""
        if not self.replay or rng.random() >= self.cfg.layout_replay:
            return None
        return self.replay.pop(int(rng.integers(len(self.replay))))

    def _layout(self, rng: np.random.Generator) -> Track:
        if self.base_track is None:
            n_gates = self.num_gates or RANDOM_TRACK_GATES
            if self.difficulty is None:
                track = random_track(n_gates, rng)
            else:
                track = race_track(n_gates, rng, difficulty=self.difficulty)
        else:
            track = self.base_track
            if self.num_gates is not None and self.num_gates < len(track.gates):
                track = replace(
                    track,
                    gates=track.gates[: self.num_gates],
                    laps=1,
                    bounds_min=None,
                    bounds_max=None,
                )
        return track

    def _jitter(self, track: Track, rng: np.random.Generator) -> Track:
        r = self.cfg.randomization
        if r.enabled and (r.gate_pos_jitter_m > 0 or r.gate_yaw_jitter_deg > 0):
            track = jitter_track(track, rng, r.gate_pos_jitter_m, r.gate_yaw_jitter_deg)
        return track

    # -- episodes ----------------------------------------------------------------------------
    def seed(self, seeds: list[int | None]) -> None:
        for i, s in enumerate(seeds):
            if s is not None:
                self.rngs[i] = np.random.default_rng(s)

    def reset_drones(self, idx: np.ndarray) -> QuadState:
        """Start new episodes for drones ``idx``; returns their initial states."""
        cfg, r = self.cfg, self.cfg.randomization
        state = QuadState.zeros(len(idx))
        start_yaw = np.zeros(len(idx))
        restored, planned = [], []
        for k, i in enumerate(idx):
            rng = self.rngs[i]
            moment = self._replay_crash(rng)
            if moment is not None:
                restored.append((k, i, moment))
                continue
            layout = self._replay_layout(rng)
            self.replayed[i] = layout is not None
            layout = self._layout(rng) if layout is None else layout
            track = self._jitter(layout, rng)
            random_layout = self.base_track is None and self.difficulty is not None
            self._set_track(i, layout, track, self.difficulty if random_layout else np.nan)
            m = len(track.passages)
            mass, thrust_max = cfg.quad.mass, cfg.quad.thrust_max
            tau, drag = cfg.quad.motor_tau, np.array(cfg.quad.drag, float)
            self.wind_const[i] = 0.0
            self.gust_amp[i] = 0.0
            start = np.array(track.start_pos, float)
            if r.enabled:
                mass *= rng.uniform(1 - r.mass_pct, 1 + r.mass_pct)
                thrust_max *= rng.uniform(1 - r.thrust_pct, 1 + r.thrust_pct)
                wind = sample_wind(rng, r.wind_mps, r.gust_mps)
                self.wind_const[i], self.gust_amp[i], self.gust_freq[i], self.gust_phase[i] = wind
                if r.start_pos_jitter_m > 0:
                    start[:2] += rng.uniform(-r.start_pos_jitter_m, r.start_pos_jitter_m, 2)
                # drawn only when asked, so configs without them keep their episodes
                if r.motor_tau_pct > 0:
                    tau *= rng.uniform(1 - r.motor_tau_pct, 1 + r.motor_tau_pct)
                if r.drag_pct > 0:
                    drag *= rng.uniform(1 - r.drag_pct, 1 + r.drag_pct, 3)
            self.params.mass[i], self.params.thrust_max[i] = mass, thrust_max
            self.params.motor_tau[i], self.params.drag[i] = tau, drag
            state.pos[k] = start
            self.start_pos[i] = start
            start_yaw[k] = math.radians(track.start_yaw_deg)
            self.max_t[i] = cfg.max_episode_s if cfg.max_episode_s is not None else 5.0 + 3.0 * m
            self.lap_times[i] = []
            node = self._plan_node(rng, m)
            if node is not None:
                planned.append((k, i, node))
        state.quat[:] = rpy_to_quat(np.stack((0 * start_yaw, 0 * start_yaw, start_yaw), axis=1))
        self.target[idx] = 0
        self.prev_action[idx] = np.nan
        self.t[idx] = 0.0
        self.taken_off[idx] = False
        self.lap_start[idx] = 0.0
        self.last_lap_time[idx] = np.nan
        self.finish_t[idx] = np.nan
        self.ep_return[idx] = 0.0
        for sums in self.ep_terms.values():
            sums[idx] = 0.0
        self.ep_len[idx] = 0
        self.n_laps[idx] = 0
        if self.cfg.crash_replay > 0:
            self.snaps["t"][idx] = np.nan
        for k, i, moment in restored:
            self._restore(k, i, moment, state)
        for k, i, node in planned:
            self._start_from_plan(k, i, node, state)
        return state

    # -- crash replay ------------------------------------------------------------------------
    def _set_track(self, i: int, layout: Track, track: Track, difficulty: float) -> None:
        """Drone ``i`` flies ``track`` (``layout`` before the jitter) from its next step."""
        self.layouts[i], self.tracks[i] = layout, track
        self.ep_difficulty[i] = difficulty
        passages = track.passages
        m = len(passages)
        self.g_mask[i] = False
        self.g_mask[i, :m] = True
        self.g_pos[i, :m] = [g.pos for g in passages]
        self.g_yaw[i, :m] = [g.yaw for g in passages]
        self.g_cos[i], self.g_sin[i] = np.cos(self.g_yaw[i]), np.sin(self.g_yaw[i])
        self.g_size[i, :m] = [g.size for g in passages]
        self.g_fw[i, :m] = [g.frame_width for g in passages]
        self.g_reach[i] = np.sqrt(2.0) * (self.g_size[i] / 2 + self.g_fw[i]) + self.g_fw[i]
        self.n_pass[i] = m
        self.gates_per_lap[i] = len(track.gates)
        self.bounds_lo[i], self.bounds_hi[i] = track.bounds_min, track.bounds_max

    def _replay_crash(self, rng: np.random.Generator) -> dict | None:
        """A moment before a crash to start from, or None (``cfg.crash_replay``)."""
        if not self.crashes or rng.random() >= self.cfg.crash_replay:
            return None
        return self.crashes.pop(int(rng.integers(len(self.crashes))))

    def _snapshot(self, state: QuadState, live: np.ndarray) -> None:
        """Record the flight of drones ``live`` (bool (N,)) every ``SNAPSHOT_S``."""
        due = live & (self.ep_len % self._snap_every == 0)
        if not due.any():
            return
        rows = np.flatnonzero(due)
        slot = (self.ep_len[rows] // self._snap_every) % SNAPSHOT_SLOTS
        s = self.snaps
        for name in _SNAP_STATE:
            s[name][rows, slot] = getattr(state, name)[rows]
        s["prev_action"][rows, slot] = self.prev_action[rows]
        s["t"][rows, slot] = self.t[rows]
        s["lap_start"][rows, slot] = self.lap_start[rows]
        s["target"][rows, slot] = self.target[rows]
        s["laps"][rows, slot] = self.n_laps[rows]

    def _keep_crash(self, i: int) -> None:
        """Keep the moment of drone ``i``'s flight about ``crash_replay_s`` before its crash."""
        s, rng = self.snaps, self.rngs[i]
        age = self.t[i] - s["t"][i]  # NaN for empty slots
        back = rng.uniform(*self.cfg.crash_replay_s)
        ok = np.flatnonzero(age >= self.cfg.crash_replay_s[0] - 1e-9)
        if len(ok) == 0:
            return
        j = ok[np.argmin(np.abs(age[ok] - back))]
        p = self.params
        self.crashes.append({
            "layout": self.layouts[i], "track": self.tracks[i],
            "difficulty": self.ep_difficulty[i], "start_pos": self.start_pos[i].copy(),
            "max_t": self.max_t[i], "mass": p.mass[i], "thrust_max": p.thrust_max[i],
            "motor_tau": p.motor_tau[i], "drag": p.drag[i].copy(),
            "wind": (self.wind_const[i].copy(), self.gust_amp[i].copy(),
                     self.gust_freq[i].copy(), self.gust_phase[i].copy()),
            "lap_times": self.lap_times[i][: s["laps"][i, j]],
            **{k: np.copy(v[i, j]) for k, v in s.items() if k != "laps"},
        })  # fmt: skip
        del self.crashes[:-REPLAY_CAPACITY]

    def _restore(self, k: int, i: int, m: dict, state: QuadState) -> None:
        """Drone ``i`` (row ``k`` of ``state``) starts from the kept moment ``m``."""
        self._set_track(i, m["layout"], m["track"], m["difficulty"])
        p = self.params
        p.mass[i], p.thrust_max[i], p.motor_tau[i] = m["mass"], m["thrust_max"], m["motor_tau"]
        p.drag[i] = m["drag"]
        self.wind_const[i], self.gust_amp[i], self.gust_freq[i], self.gust_phase[i] = m["wind"]
        self.start_pos[i], self.max_t[i] = m["start_pos"], m["max_t"]
        for name in _SNAP_STATE:
            getattr(state, name)[k] = m[name]
        self.prev_action[i] = m["prev_action"]
        self.t[i], self.lap_start[i], self.target[i] = m["t"], m["lap_start"], m["target"]
        self._resume(i, m["lap_times"])

    def _resume(self, i: int, lap_times: list[float]) -> None:
        """Drone ``i`` goes on mid-race (a crash replay or a plan start) with ``lap_times`` done:
        in the air, and not a start the curriculum counts."""
        self.replayed[i] = True
        self.taken_off[i] = True
        self.lap_times[i] = list(lap_times)
        self.n_laps[i] = len(self.lap_times[i])
        self.last_lap_time[i] = self.lap_times[i][-1] if self.lap_times[i] else np.nan

    def wind(self) -> np.ndarray:
        """(N, 3) world air velocity at the current time of each drone, m/s."""
        t = self.t[:, None, None]
        gust = (self.gust_amp * np.sin(2 * math.pi * self.gust_freq * t + self.gust_phase)).sum(
            axis=1
        )
        return self.wind_const + gust

    def target_gate(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Target passage of each drone (the last one once all are passed): pos (N, 3), yaw (N,), size (N,)."""
        j = np.minimum(self.target, self.n_pass - 1)
        rows = np.arange(self.n)
        return self.g_pos[rows, j], self.g_yaw[rows, j], self.g_size[rows, j]

    # -- rules -------------------------------------------------------------------------------
    def frame_collision(self, trail: np.ndarray) -> np.ndarray:
        """(N,) bool: any sub-step position (trail (S, N, 3)) within the drone radius of a bar.

        A broad phase keeps only (drone, gate) pairs whose centres are within reach of each other
        at the end of the step; the exact bar distance is computed for those pairs alone.
        """
        return rules.trail_frame_collision(
            trail,
            self.params.radius,
            self.g_pos,
            self.g_cos,
            self.g_sin,
            self.g_size,
            self.g_fw,
            self.g_reach,
            self.g_mask,
        )

    def finish_step(
        self,
        p0: np.ndarray,
        state: QuadState,
        frame_hit: np.ndarray,
        ground_hit: np.ndarray,
        trail: np.ndarray | None = None,
        action: np.ndarray | None = None,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict]:
        """Apply the rules after the physics of one control step.

        Args:
            p0: (N, 3) positions before the step.
            state: states after the step.
            frame_hit, ground_hit: (N,) bool collisions reported by the backend.
            trail: (S, N, 3) sub-step positions for the bounds check (None: end position only).
            action: (N, 4) the action of this step (for the action-change cost; None: no cost).

        Returns:
            reward (N,), terminated (N,), truncated (N,), crash_code (N,) int (-1 none, else index in
            rules.CRASH_REASONS), and the named reward terms.
        """
        cfg = self.cfg
        dt = cfg.dt
        gpos, gyaw, gsize = self.target_gate()
        active = self.target < self.n_pass
        prev_dist = np.linalg.norm(gpos - p0, axis=1)
        to_gate = gpos - state.pos
        dist = np.linalg.norm(to_gate, axis=1)
        passed, centrality, fraction = rules.gate_crossing(p0, state.pos, gpos, gyaw, gsize)
        passed &= active
        pts = trail if trail is not None else state.pos[None]
        oob = rules.out_of_bounds(pts, self.bounds_lo, self.bounds_hi).any(axis=0)
        ground = ground_hit & self.taken_off
        crash_code = np.where(frame_hit, 0, np.where(ground, 1, np.where(oob, 2, -1)))
        crashed = crash_code >= 0
        self.taken_off |= state.pos[:, 2] >= self.params.radius + TAKEOFF_CLEARANCE
        rpy = self.last_rpy = quat_to_rpy(state.quat)
        w = cfg.reward
        extra = {}
        j = np.minimum(self.target, self.n_pass - 1)  # each drone's target passage
        if w.line:
            rows = np.arange(self.n)
            seg_from = np.where((j > 0)[:, None], self.g_pos[rows, j - 1], self.start_pos)
            extra["line"] = reward_line(p0, state.pos, seg_from, gpos)
        if w.path:
            if self.ref_path is None:
                raise RuntimeError("the path reward needs a reference: RaceCore.set_reference")
            extra["path"] = reward_path(p0, state.pos, self.ref_path[j], self.ref_arc[j])
        if w.perception:
            uptilt = np.radians(cfg.quad.camera.uptilt_deg)
            extra["camera_angle"] = camera_gate_angle(quat_to_rot(state.quat), to_gate, uptilt)
        if w.rates:
            extra["omega"] = state.omega
        if w.center:
            extra["centrality"] = np.where(passed, centrality, 0.0)
        if w.align:
            alignment = rules.crossing_alignment(p0, state.pos, gyaw)
            extra["alignment"] = np.where(passed, alignment, 0.0)
        if w.action_change:
            a = self.prev_action if action is None else action
            extra["action_change"] = cost_action_change(a, self.prev_action)
            self.prev_action[:] = a
        reward, terms = compute_reward(
            w, prev_dist=prev_dist, dist=dist, passed=passed, crashed=crashed,
            rpy=rpy, vel=state.vel, to_gate=to_gate, dt=dt, **extra,
        )  # fmt: skip
        crossed_at = self.t + fraction * dt  # a passage's time: where in the step it was made
        self.t += dt
        self.target += passed
        lap_done = passed & (self.target % self.gates_per_lap == 0)
        if lap_done.any():
            for i in np.flatnonzero(lap_done):
                lap = float(crossed_at[i] - self.lap_start[i])
                self.lap_times[i].append(lap)
                self.n_laps[i] += 1
                self.last_lap_time[i] = lap
                self.lap_start[i] = crossed_at[i]
        all_passed = self.target >= self.n_pass
        finished = passed & all_passed
        self.finish_t[finished] = crossed_at[finished]
        terminated = crashed | all_passed
        truncated = (self.t >= self.max_t - 1e-9) & ~terminated
        if self.cfg.layout_replay > 0 and self.base_track is None:
            for i in np.flatnonzero((terminated | truncated) & ~all_passed):
                self.replay.append(self.layouts[i])
            del self.replay[:-REPLAY_CAPACITY]
        if self.cfg.crash_replay > 0:
            for i in np.flatnonzero(crashed):
                self._keep_crash(i)
            self._snapshot(state, ~(terminated | truncated))
        self.ep_return += reward
        for k, v in terms.items():
            self.ep_terms.setdefault(k, np.zeros(self.n))[:] += v
        self.ep_len += 1
        return reward, terminated, truncated, crash_code, terms

    def observe(self, state: QuadState, rpy: np.ndarray | None = None) -> np.ndarray:
        """(N, 15) float32: pos, vel, rpy, body rates, next gate relative position (world or body).

        With ``observation="extended"``, (N, 21): plus the next gate's passage direction and the
        relative position of the gate after it (the last gate repeats at the end of the course).
        With ``observation="racing"``, (N, 25): plus the next gate's opening side and the gate
        after's passage direction. ``rpy`` (N, 3) may be passed when already computed for this state.
        """
        rpy = quat_to_rpy(state.quat) if rpy is None else rpy
        gpos, gyaw, gsize = self.target_gate()
        nxt = size = after_yaw = None
        if self.cfg.observation != "basic":
            rows = np.arange(self.n)
            j = np.minimum(self.target + 1, self.n_pass - 1)
            nxt = self.g_pos[rows, j]
            if self.cfg.observation == "racing":
                size, after_yaw = gsize, self.g_yaw[rows, j]
        return observation_vector(
            state, rpy, gpos, gyaw, nxt, self.cfg.gate_obs_frame, size, after_yaw
        )

    def info(self, i: int, terms: dict, crash_code: int) -> dict:
        """The info dict of drone ``i`` for the step just taken."""
        return {
            "gates_passed": int(self.target[i]),
            "gates_total": int(self.n_pass[i]),
            "all_gates_passed": bool(self.target[i] >= self.n_pass[i]),
            "crashed": bool(crash_code >= 0),
            "crash_reason": rules.CRASH_REASONS[crash_code] if crash_code >= 0 else None,
            "lap_time": None if np.isnan(self.last_lap_time[i]) else float(self.last_lap_time[i]),
            "lap_times": list(self.lap_times[i]),
            "time": float(self.t[i]),
            "finish_time": None if np.isnan(self.finish_t[i]) else float(self.finish_t[i]),
            "difficulty": None if np.isnan(self.ep_difficulty[i]) else float(self.ep_difficulty[i]),
            "replayed": bool(self.replayed[i]),
            "reward_terms": {k: float(v[i]) for k, v in terms.items()},
            "episode_reward_terms": {k: float(v[i]) for k, v in self.ep_terms.items()},
        }


__all__ = ["OBS_DIM", "RaceCore", "validate_action", "jitter_track"]
