"""Full-model minimum-time problem: multiple shooting over the lagged CTBR quadrotor (``model``).

Decision variables: the duration T_i of every gate segment (free final time = Σ T_i, each segment
split into ``nodes_per_gate`` equal intervals), the state x_k at every node and the commands u_k on
every interval. Constraints: x_0 at rest at the start pose (hovering), continuity
x_{k+1} = F(x_k, u_k, T_i / N), thrust command in [0, T_max], rate commands within ±max_rate, the
drone's centre inside the track bounds at every node, and each passage node inside its gate window
with the velocity pointing through (``geometry``). Cost: Σ T_i.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import casadi as ca
import numpy as np

from icarus_vision.planning.geometry import Layout
from icarus_vision.planning.model import NU, NX, step_function
from icarus_vision.planning.solver import SolverConfig, solve_nlp

RK4_STEP_S = 0.03  # longest RK4 sub-step: ~1e-4 m, ~1e-3 m/s error per interval (tests/planning)
INTERVAL_MARGIN = 1.5  # an interval may grow to this times the guess's longest before re-meshing


@dataclass(frozen=True, eq=False)
class FullSolution:
    """Full-model trajectory on the node layout (K intervals)."""

    segment_times: np.ndarray
    """(S,) duration of each gate segment, s."""
    states: np.ndarray
    """(K + 1, 14) node states (p, v, q, ω, τ), see ``model``."""
    controls: np.ndarray
    """(K, 4) interval commands (τ_c, ω_c)."""
    status: str
    """IPOPT return status."""
    iterations: int
    """IPOPT iterations."""
    wall_s: float
    """Solve wall time, s."""
    defect: float
    """Largest continuity residual |x_{k+1} − F(x_k, u_k, h)| at the solution."""


def solve_full(
    layout: Layout,
    quad,
    guess: tuple[np.ndarray, np.ndarray, np.ndarray],
    *,
    cfg: SolverConfig | None = None,
) -> FullSolution:
    """Solve the minimum-time problem from ``guess`` = (segment times, states, controls).

    Intervals are integrated with as many RK4 sub-steps as keep each within ``RK4_STEP_S`` when the
    interval is ``INTERVAL_MARGIN`` times the guess's longest; that length is also the upper bound
    of every interval (the guess is slower than the optimum, so the bound does not bind in practice).

    Raises:
        PlanError: IPOPT did not converge (its status is in the error).
    """
    cfg = cfg or SolverConfig()
    s_n, n, k_int = layout.num_segments, layout.nodes_per_gate, layout.num_intervals
    seg_of = layout.segment_of_interval()
    t_guess, x_guess, u_guess = guess
    h_max = INTERVAL_MARGIN * float(t_guess.max()) / n
    substeps = max(1, math.ceil(h_max / RK4_STEP_S))
    step = step_function(quad, substeps)

    seg_t = ca.SX.sym("T", s_n)
    xs = [ca.SX.sym(f"x{k}", NX) for k in range(k_int + 1)]
    us = [ca.SX.sym(f"u{k}", NU) for k in range(k_int)]
    g, lbg, ubg = [], [], []

    def add(expr, lo, hi) -> None:
        g.append(expr)
        lbg.extend(np.broadcast_to(lo, (expr.shape[0],)))
        ubg.extend(np.broadcast_to(hi, (expr.shape[0],)))

    for k in range(k_int):
        add(step(xs[k], us[k], seg_t[seg_of[k]] / n) - xs[k + 1], 0.0, 0.0)
    for i, node in enumerate(layout.gate_nodes):
        for expr, lo, hi in layout.passage_constraints(i, xs[node][0:3], xs[node][3:6]):
            add(expr, lo, hi)

    rate = np.asarray(quad.max_rate, float)
    x_lo = np.concatenate([layout.pos_lo, np.full(NX - 3, -np.inf)])
    x_hi = np.concatenate([layout.pos_hi, np.full(NX - 3, np.inf)])
    u_lo = np.concatenate([[0.0], -rate])
    u_hi = np.concatenate([[1.0], rate])
    x = ca.vertcat(seg_t, *[ca.vertcat(xs[k], us[k]) for k in range(k_int)], xs[k_int])
    x0 = [t_guess]
    lbx = [np.full(s_n, 1e-3 * n)]
    ubx = [np.full(s_n, substeps * RK4_STEP_S * n)]
    for k in range(k_int + 1):
        x0.append(x_guess[k])
        lbx.append(x_guess[0] if k == 0 else x_lo)
        ubx.append(x_guess[0] if k == 0 else x_hi)
        if k < k_int:
            x0.append(u_guess[k])
            lbx.append(u_lo)
            ubx.append(u_hi)
    sol = solve_nlp(
        "full-model",
        x,
        ca.sum1(seg_t),
        ca.vertcat(*g),
        x0=np.concatenate(x0),
        lbx=np.concatenate(lbx),
        ubx=np.concatenate(ubx),
        lbg=np.asarray(lbg, float),
        ubg=np.asarray(ubg, float),
        cfg=cfg,
    )
    seg_times = sol.x[:s_n]
    body = sol.x[s_n:]
    stride = NX + NU
    states = np.array([body[stride * k : stride * k + NX] for k in range(k_int + 1)])
    controls = np.array([body[stride * k + NX : stride * (k + 1)] for k in range(k_int)])
    h = seg_times[seg_of] / n
    nxt = np.array(step.map(k_int)(states[:-1].T, controls.T, h[None, :])).T
    defect = float(np.abs(nxt - states[1:]).max())
    return FullSolution(
        segment_times=seg_times,
        states=states,
        controls=controls,
        status=sol.status,
        iterations=sol.iterations,
        wall_s=sol.wall_s,
        defect=defect,
    )
