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
from icarus_vision.planning.solver import ShootingNlp, SolverConfig

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

    nlp = ShootingNlp(s_n, NX, NU, k_int)
    xs, us, seg_t = nlp.xs, nlp.us, nlp.seg_t
    for k in range(k_int):
        nlp.add(step(xs[k], us[k], seg_t[seg_of[k]] / n) - xs[k + 1], 0.0, 0.0)
    for i, node in enumerate(layout.gate_nodes):
        for expr, lo, hi in layout.passage_constraints(i, xs[node][0:3], xs[node][3:6]):
            nlp.add(expr, lo, hi)

    rate = np.asarray(quad.max_rate, float)
    x_lo = np.tile(np.concatenate([layout.pos_lo, np.full(NX - 3, -np.inf)]), (k_int + 1, 1))
    x_hi = np.tile(np.concatenate([layout.pos_hi, np.full(NX - 3, np.inf)]), (k_int + 1, 1))
    x_lo[0] = x_hi[0] = x_guess[0]
    sol, seg_times, states, controls = nlp.solve(
        "full-model",
        ca.sum1(seg_t),
        guess=(t_guess, x_guess, u_guess),
        lower=(1e-3 * n, x_lo, np.concatenate([[0.0], -rate])),
        upper=(substeps * RK4_STEP_S * n, x_hi, np.concatenate([[1.0], rate])),
        cfg=cfg,
    )
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
