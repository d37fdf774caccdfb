"""Independent checks of a plan against the simulator's own dynamics and rules.

Each shooting interval is replayed from its planned start state with ``sim.dynamics.step_substeps``
(the batched simulator's integrator, fine sub-steps, the planned commands) and compared with the next
planned node; the dense replay is then run through ``sim.rules`` for gate passages and bar contacts.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from icarus_vision.planning.result import PlanResult
from icarus_vision.sim.dynamics import QuadBatchParams, QuadState, step_substeps
from icarus_vision.sim.quad import QuadParams
from icarus_vision.sim.rules import frame_collision, gate_passage
from icarus_vision.sim.track import Track


@dataclass(frozen=True, eq=False)
class Replay:
    """Interval-wise replay of a plan in the simulator's dynamics."""

    pos_error_m: float
    """Largest |p_replayed − p_planned| at the end of any interval, m."""
    vel_error_mps: float
    """Largest velocity mismatch at the end of any interval, m/s."""
    trail: np.ndarray
    """(M, 3) dense replayed positions, in time order."""


def replay_intervals(plan: PlanResult, quad: QuadParams, max_dt: float = 5e-4) -> Replay:
    """Replay every interval of ``plan`` from its planned start state with the simulator's integrator."""
    dt = np.diff(plan.t)
    k_int = len(dt)
    pos_err = np.zeros(k_int)
    vel_err = np.zeros(k_int)
    chunks: list[np.ndarray] = [plan.pos[:1]]
    start = 0
    while start < k_int:  # intervals of equal length (one gate segment) run as one batch
        end = start + 1
        while end < k_int and abs(dt[end] - dt[start]) < 1e-12:
            end += 1
        idx = np.arange(start, end)
        h = float(dt[start])
        sub = max(1, math.ceil(h / max_dt))
        state = QuadState(
            pos=plan.pos[idx].copy(),
            vel=plan.vel[idx].copy(),
            quat=plan.quat[idx].copy(),
            omega=plan.rates[idx].copy(),
            thrust=plan.thrust[idx].copy(),
        )
        params = QuadBatchParams.from_quad(quad, len(idx))
        wind = np.zeros((len(idx), 3))
        trail = step_substeps(
            state, plan.thrust_cmd[idx], plan.rate_cmd[idx], wind, params, h / sub, sub
        )
        pos_err[idx] = np.linalg.norm(state.pos - plan.pos[idx + 1], axis=1)
        vel_err[idx] = np.linalg.norm(state.vel - plan.vel[idx + 1], axis=1)
        chunks.append(trail.transpose(1, 0, 2).reshape(-1, 3))
        start = end
    return Replay(float(pos_err.max()), float(vel_err.max()), np.vstack(chunks))


def passages_in_order(trail: np.ndarray, track: Track) -> int:
    """How many gate passages (all laps, in order) a dense position trail makes under the race rules."""
    passages = track.passages
    j = 0
    for p0, p1 in zip(trail[:-1], trail[1:], strict=True):
        if j == len(passages):
            break
        g = passages[j]
        if gate_passage(
            p0[None], p1[None], np.array([g.pos]), np.array([g.yaw]), np.array([g.size])
        )[0]:
            j += 1
    return j


def bar_contacts(trail: np.ndarray, track: Track, radius: float) -> int:
    """Number of trail points whose collision sphere touches a gate bar (0 for a clean plan)."""
    gates = track.physical_gates()
    n = len(trail)
    gpos = np.broadcast_to(np.array([g.pos for g in gates]), (n, len(gates), 3))
    gyaw = np.broadcast_to(np.array([g.yaw for g in gates]), (n, len(gates)))
    size = np.broadcast_to(np.array([g.size for g in gates]), (n, len(gates)))
    fw = np.broadcast_to(np.array([g.frame_width for g in gates]), (n, len(gates)))
    mask = np.ones((n, len(gates)), bool)
    return int(frame_collision(trail, radius, gpos, gyaw, size, fw, mask).sum())
