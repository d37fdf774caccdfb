"""Thin wrapper around CasADi's IPOPT interface: quiet options, status handling, timing."""

from __future__ import annotations

import re
import time
from dataclasses import dataclass

import casadi as ca
import numpy as np

from icarus_vision.planning.result import PlanError

ACCEPTED_STATUS = ("Solve_Succeeded", "Solved_To_Acceptable_Level")


@dataclass(frozen=True)
class SolverConfig:
    """IPOPT settings shared by the point-mass and full-model solves."""

    max_iter: int = 3000
    """Iteration limit; reaching it is a failure (``Maximum_Iterations_Exceeded``)."""
    max_cpu_s: float = 600.0
    """CPU-time limit of one solve, s (``Maximum_CpuTime_Exceeded``)."""
    print_level: int = 0
    """IPOPT verbosity, 0 (silent) to 12."""
    tol: float = 1e-6
    """IPOPT convergence tolerance."""


@dataclass(frozen=True)
class NlpSolution:
    """Primal solution of one NLP."""

    x: np.ndarray
    """Optimal decision vector."""
    status: str
    """IPOPT return status."""
    iterations: int
    """IPOPT iterations."""
    wall_s: float
    """Wall time of the solve (not of building the problem), s."""


def solve_nlp(
    what: str,
    x: ca.SX,
    f: ca.SX,
    g: ca.SX,
    *,
    x0: np.ndarray,
    lbx: np.ndarray,
    ubx: np.ndarray,
    lbg: np.ndarray,
    ubg: np.ndarray,
    cfg: SolverConfig,
) -> NlpSolution:
    """Minimise f(x) s.t. lbg <= g(x) <= ubg, lbx <= x <= ubx with IPOPT.

    Raises:
        PlanError: with IPOPT's return status when it does not converge (``what`` names the stage).
    """
    opts = {
        "ipopt.print_level": int(cfg.print_level),
        "ipopt.sb": "yes",
        "ipopt.max_iter": int(cfg.max_iter),
        "ipopt.max_cpu_time": float(cfg.max_cpu_s),
        "ipopt.tol": float(cfg.tol),
        "ipopt.mu_strategy": "adaptive",
        "print_time": False,
        "verbose": False,
    }
    solver = ca.nlpsol(re.sub(r"\W+", "_", what), "ipopt", {"x": x, "f": f, "g": g}, opts)
    t0 = time.perf_counter()
    sol = solver(x0=np.clip(x0, lbx, ubx), lbx=lbx, ubx=ubx, lbg=lbg, ubg=ubg)
    wall = time.perf_counter() - t0
    stats = solver.stats()
    status = str(stats.get("return_status", "unknown"))
    iters = int(stats.get("iter_count", -1))
    if status not in ACCEPTED_STATUS:
        raise PlanError(status, f"{what}: IPOPT stopped after {iters} iterations ({wall:.1f} s)")
    xs = np.asarray(sol["x"], float).ravel()
    if not np.all(np.isfinite(xs)):
        raise PlanError(status, f"{what}: IPOPT returned non-finite values")
    return NlpSolution(x=xs, status=status, iterations=iters, wall_s=wall)
