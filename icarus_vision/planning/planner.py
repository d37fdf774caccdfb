"""``plan``: minimum-time trajectory of a quadrotor through a track's gates, with an on-disk cache.

Pipeline: gate windows and bounds (``geometry``) -> point-mass lower bound (``point_mass``) ->
point-mass guess with derated thrust and smoothing -> full-model guess (``guess``) -> full-model
multiple-shooting solve (``minimum_time``) -> post-solve checks (residuals; replay in the simulator's
integrator for bar contacts) -> cache.
"""

from __future__ import annotations

import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from icarus_vision.planning.cache import DEFAULT_CACHE_DIR, load_cached, save_cached
from icarus_vision.planning.geometry import Layout, build_layout, default_tol
from icarus_vision.planning.guess import full_guess
from icarus_vision.planning.minimum_time import FullSolution, solve_full
from icarus_vision.planning.point_mass import solve_point_mass
from icarus_vision.planning.result import PlanError, PlanResult
from icarus_vision.planning.solver import SolverConfig
from icarus_vision.planning.verify import bar_contacts, replay_intervals
from icarus_vision.sim.quad import QuadParams
from icarus_vision.sim.track import Track

GUESS_THRUST_SCALES = (0.8, 0.6)  # derating of the point-mass guess; the next one is a retry
GUESS_SMOOTHING = 1e-2
CHECK_TOL = 1e-3  # largest continuity / gate-window residual accepted after the solve
REPLAY_DT = 1e-3  # s, simulator sub-step of the post-solve replay that looks for bar contacts


def plan(
    track: Track,
    quad: QuadParams | None = None,
    *,
    nodes_per_gate: int = 20,
    tol: float | None = None,
    cache_dir: str | Path | None = DEFAULT_CACHE_DIR,
    use_cache: bool = True,
    solver: SolverConfig | None = None,
) -> PlanResult:
    """Minimum-time trajectory from rest at the start through every gate passage (all laps), in order.

    Args:
        track: the course; every passage of ``track.passages`` is a waypoint.
        quad: quadrotor (default ``QuadParams()``); thrust in [0, T_max], rates within ±max_rate.
        nodes_per_gate: shooting intervals per gate segment (each segment's duration is free).
        tol: margin kept from the opening's inner edge at each crossing, m (default: the drone's
            collision radius + 5 cm).
        cache_dir: folder of the plan cache (None: neither read nor write a cache).
        use_cache: return a cached plan made with the same options instead of solving.
        solver: IPOPT settings (default: silent, 3000 iterations, 600 s).

    Returns:
        The plan; ``success`` is True (failures raise).

    Raises:
        ValueError: bad ``nodes_per_gate`` or ``tol``.
        PlanError: infeasible track (presolve or IPOPT), solver failure, or a solution that fails
            the post-solve checks; ``.status`` holds the status. Nothing is written then.
    """
    quad = quad or QuadParams()
    tol = default_tol(quad) if tol is None else float(tol)
    cfg = solver or SolverConfig()
    if cache_dir is not None and use_cache:
        hit = load_cached(track, quad, cache_dir, nodes_per_gate=nodes_per_gate, tol=tol)
        if hit is not None:
            return hit
    t0 = time.perf_counter()
    layout = build_layout(track, quad, nodes_per_gate, tol)
    bound = solve_point_mass(layout, quad, cfg=cfg)
    full = _solve_with_retries(layout, quad, cfg)
    solve_time = time.perf_counter() - t0
    _check(full, layout)
    result = _to_result(track, quad, layout, bound.total_time, full, solve_time, tol)
    trail = replay_intervals(result, quad, max_dt=REPLAY_DT).trail
    contact = bar_contacts(trail[1:], track, quad.radius) * REPLAY_DT
    result = replace(result, bar_contact_s=float(contact))
    if cache_dir is not None:
        save_cached(result, track, quad, cache_dir)
    return result


def _solve_with_retries(layout: Layout, quad: QuadParams, cfg: SolverConfig) -> FullSolution:
    """Full-model solve from the derated point-mass guess, retrying with a more derated one."""
    error: PlanError | None = None
    for scale in GUESS_THRUST_SCALES:
        try:
            pm = solve_point_mass(
                layout, quad, thrust_scale=scale, smoothing=GUESS_SMOOTHING, cfg=cfg
            )
            return solve_full(layout, quad, full_guess(pm, layout, quad), cfg=cfg)
        except PlanError as e:
            error = e
            if e.status in ("Infeasible_Problem_Detected", "Maximum_CpuTime_Exceeded"):
                break
    assert error is not None
    raise error


def _check(full: FullSolution, layout: Layout) -> None:
    """Refuse a solution whose dynamics or gate constraints are violated beyond CHECK_TOL."""
    if full.defect > CHECK_TOL:
        raise PlanError(
            "Verification_Failed",
            f"the solution violates the dynamics by {full.defect:.2e} (> {CHECK_TOL}) "
            f"after IPOPT returned {full.status}",
        )
    for i, node in enumerate(layout.gate_nodes):
        p, v = full.states[node, 0:3], full.states[node, 3:6]
        for expr, lo, hi in layout.passage_constraints(i, p, v):
            if not lo - CHECK_TOL <= float(expr) <= hi + CHECK_TOL:
                raise PlanError(
                    "Verification_Failed",
                    f"passage {i} misses its window after IPOPT returned {full.status}",
                )


def _to_result(
    track: Track,
    quad: QuadParams,
    layout: Layout,
    point_mass_s: float,
    full: FullSolution,
    solve_time: float,
    tol: float,
) -> PlanResult:
    dt = full.segment_times[layout.segment_of_interval()] / layout.nodes_per_gate
    x, u = full.states, full.controls
    rate = np.asarray(quad.max_rate, float)
    return PlanResult(
        track=track.name,
        quad=quad.name,
        laps=track.laps,
        time_optimal_s=float(full.segment_times.sum()),
        point_mass_s=float(point_mass_s),
        solver_status=full.status,
        solve_time_s=float(solve_time),
        success=True,
        iterations=full.iterations,
        nodes_per_gate=layout.nodes_per_gate,
        tol=float(tol),
        bar_contact_s=0.0,
        t=np.concatenate([[0.0], np.cumsum(dt)]),
        pos=x[:, 0:3].copy(),
        vel=x[:, 3:6].copy(),
        quat=x[:, 6:10] / np.linalg.norm(x[:, 6:10], axis=1, keepdims=True),
        thrust=x[:, 13] * quad.thrust_max,
        rates=x[:, 10:13].copy(),
        thrust_cmd=np.clip(u[:, 0], 0.0, 1.0) * quad.thrust_max,
        rate_cmd=np.clip(u[:, 1:4], -rate, rate),
        gate_nodes=layout.gate_nodes.copy(),
    )
