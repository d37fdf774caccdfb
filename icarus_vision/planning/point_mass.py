"""Point-mass minimum-time problem: the lower bound and the full model's initial guess.

Model: a point mass whose world acceleration ``a`` is piecewise constant on each shooting interval
(positions and velocities integrate exactly). Its specific force ``a − g`` is the full model's thrust
plus drag with the attitude left free, relaxed to a ball:

    | a − g + c v | <= T_max/m + e |v|,   c = min(drag)/m,  e = (max(drag) − min(drag))/m

(body-frame drag R D Rᵀ v = d_min v + R (D − d_min I) Rᵀ v, and the second term has norm at most
(d_max − d_min)|v|). Every full-model trajectory satisfies this, so up to discretisation the optimum
is a lower bound on the full model's time. The constraint is enforced at both ends of every interval.
With no drag it is the classic thrust-limited point mass, whose straight-line time from rest is
``bang_bang_time``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import casadi as ca
import numpy as np

from icarus_vision.planning.geometry import (
    Layout,
    thrust_accel_limit,
    waypoint_polyline,
)
from icarus_vision.planning.solver import ShootingNlp, SolverConfig
from icarus_vision.sim.quad import GRAVITY, QuadParams

G_VEC = np.array([0.0, 0.0, -GRAVITY])


def bang_bang_time(distance: float, quad: QuadParams) -> float:
    """Analytic minimum time of a thrust-limited, drag-free point mass from rest over a level line.

    The full thrust T_max/m is tilted to hold altitude, leaving a horizontal acceleration
    a_h = sqrt((T_max/m)² − g²) for the whole distance: t = sqrt(2 d / a_h).
    """
    a_h = math.sqrt(thrust_accel_limit(quad) ** 2 - GRAVITY**2)
    return math.sqrt(2.0 * distance / a_h)


@dataclass(frozen=True, eq=False)
class PointMassSolution:
    """Point-mass trajectory on the planner's node layout (K intervals, K + 1 nodes)."""

    t: np.ndarray
    """(K + 1,) node times, s."""
    pos: np.ndarray
    """(K + 1, 3) world position, m."""
    vel: np.ndarray
    """(K + 1, 3) world velocity, m/s."""
    acc: np.ndarray
    """(K, 3) world acceleration held on each interval, m/s²."""
    segment_times: np.ndarray
    """(S,) duration of each gate segment, s."""
    status: str
    """IPOPT return status."""
    iterations: int
    """IPOPT iterations."""
    wall_s: float
    """Solve wall time, s."""

    @property
    def total_time(self) -> float:
        return float(self.segment_times.sum())


def _straight_guess(layout: Layout, a_h: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Segment times, node positions and velocities along the gate polyline at a modest speed."""
    pts = waypoint_polyline(layout)
    seg = np.diff(pts, axis=0)
    dist = np.maximum(np.linalg.norm(seg, axis=1), 1e-3)
    v_g = float(np.clip(0.25 * math.sqrt(a_h * dist.sum()), 2.0, 20.0))
    times = dist / v_g
    times[0] = max(times[0], 2.0 * math.sqrt(dist[0] / a_h))
    n = layout.nodes_per_gate
    s = np.linspace(0.0, 1.0, n + 1)[:-1]
    pos = [pts[i] + s[:, None] * seg[i] for i in range(len(seg))]
    vel = [np.repeat((seg[i] / times[i])[None], n, axis=0) for i in range(len(seg))]
    pos = np.vstack([*pos, pts[-1:]])
    vel = np.vstack([*vel, vel[-1][-1:]])
    vel[0] = 0.0
    return times, pos, vel


def solve_point_mass(
    layout: Layout,
    quad: QuadParams,
    *,
    thrust_scale: float = 1.0,
    smoothing: float = 0.0,
    cfg: SolverConfig | None = None,
) -> PointMassSolution:
    """Minimum-time point-mass trajectory through every gate window, from rest at the start.

    Args:
        layout: passages, node layout and bounds (``geometry.build_layout``).
        quad: thrust, mass and drag limits.
        thrust_scale: scale on T_max (1 for the lower bound; < 1 leaves margin for a guess).
        smoothing: weight of a penalty on acceleration changes between intervals (0 for the bound).
        cfg: IPOPT settings.

    Raises:
        PlanError: the solver did not converge (status in the error).
    """
    cfg = cfg or SolverConfig()
    a_max = thrust_scale * thrust_accel_limit(quad)
    drag = np.asarray(quad.drag, float) / quad.mass
    c, e = float(drag.min()), float(drag.max() - drag.min())
    s_n, n = layout.num_segments, layout.nodes_per_gate
    k_int = layout.num_intervals
    seg_of = layout.segment_of_interval()

    nlp = ShootingNlp(s_n, 6, 3, k_int)
    seg_t, z, a = nlp.seg_t, nlp.xs, nlp.us

    def thrust_ok(acc, v) -> None:
        f = acc - G_VEC + c * v
        lim = a_max + e * ca.sqrt(ca.sumsqr(v) + 1e-6) if e > 0 else a_max
        nlp.add(ca.sumsqr(f) - lim**2, -ca.inf, 0.0)

    for k in range(k_int):
        h = seg_t[seg_of[k]] / n
        p, v = z[k][:3], z[k][3:]
        nlp.add(z[k + 1][:3] - (p + v * h + 0.5 * a[k] * h**2), 0.0, 0.0)
        nlp.add(z[k + 1][3:] - (v + a[k] * h), 0.0, 0.0)
        thrust_ok(a[k], v)
        if c > 0 or e > 0:
            thrust_ok(a[k], z[k + 1][3:])
    for i, node in enumerate(layout.gate_nodes):
        for expr, lo, hi in layout.passage_constraints(i, z[node][:3], z[node][3:]):
            nlp.add(expr, lo, hi)

    cost = ca.sum1(seg_t)
    if smoothing > 0:
        cost += smoothing * sum(ca.sumsqr(a[k + 1] - a[k]) for k in range(k_int - 1)) / a_max**2

    a_h = math.sqrt(max(a_max**2 - GRAVITY**2, 1e-6))
    t_guess, p_guess, v_guess = _straight_guess(layout, a_h)
    z_lo = np.tile(np.concatenate([layout.pos_lo, np.full(3, -np.inf)]), (k_int + 1, 1))
    z_hi = np.tile(np.concatenate([layout.pos_hi, np.full(3, np.inf)]), (k_int + 1, 1))
    z_lo[0] = z_hi[0] = np.concatenate([layout.start, np.zeros(3)])
    sol, seg_times, nodes, acc = nlp.solve(
        "point-mass",
        cost,
        guess=(t_guess, np.concatenate([p_guess, v_guess], axis=1), 0.0),
        lower=(1e-3 * n, z_lo, -np.inf),
        upper=(1e3, z_hi, np.inf),
        cfg=cfg,
    )
    dt = seg_times[seg_of] / n
    t = np.concatenate([[0.0], np.cumsum(dt)])
    return PointMassSolution(
        t=t,
        pos=nodes[:, :3],
        vel=nodes[:, 3:],
        acc=acc,
        segment_times=seg_times,
        status=sol.status,
        iterations=sol.iterations,
        wall_s=sol.wall_s,
    )
