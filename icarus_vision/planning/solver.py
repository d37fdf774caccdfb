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


class ShootingNlp:
    """A multiple-shooting NLP: decision vector [T (segment durations), x_0, u_0, x_1, u_1, …, x_K],
    its constraints, and the bounds and guess laid out in the same order.

    Both the point-mass and the full-model problems are built on this, so the vector layout lives in
    one place.
    """

    def __init__(self, num_segments: int, nx: int, nu: int, num_intervals: int) -> None:
        self.nx, self.nu, self.num_intervals = nx, nu, num_intervals
        self.seg_t = ca.SX.sym("T", num_segments)
        self.xs = [ca.SX.sym(f"x{k}", nx) for k in range(num_intervals + 1)]
        self.us = [ca.SX.sym(f"u{k}", nu) for k in range(num_intervals)]
        self._g: list[ca.SX] = []
        self._lbg: list[float] = []
        self._ubg: list[float] = []

    def add(self, expr: ca.SX, lo, hi) -> None:
        """Constrain lo <= expr <= hi (bounds broadcast over the expression's rows)."""
        self._g.append(expr)
        self._lbg.extend(np.broadcast_to(lo, (expr.shape[0],)))
        self._ubg.extend(np.broadcast_to(hi, (expr.shape[0],)))

    def _pack(self, t, x, u) -> np.ndarray:
        k = self.num_intervals
        x = np.broadcast_to(np.asarray(x, float), (k + 1, self.nx))
        u = np.broadcast_to(np.asarray(u, float), (k, self.nu))
        body = np.concatenate([np.concatenate([x[:k], u], axis=1).ravel(), x[k]])
        return np.concatenate([np.broadcast_to(np.asarray(t, float), self.seg_t.shape[:1]), body])

    def solve(
        self,
        what: str,
        cost: ca.SX,
        *,
        guess: tuple,
        lower: tuple,
        upper: tuple,
        cfg: SolverConfig,
    ) -> tuple[NlpSolution, np.ndarray, np.ndarray, np.ndarray]:
        """Solve; ``guess``, ``lower`` and ``upper`` are each (segment times, node states (K+1, nx),
        interval controls (K, nu)), broadcast to those shapes.

        Returns:
            The solution, and from it the segment times (S,), states (K+1, nx), controls (K, nu).
        """
        k = self.num_intervals
        blocks = [ca.vertcat(self.xs[i], self.us[i]) for i in range(k)]
        x = ca.vertcat(self.seg_t, *blocks, self.xs[k])
        sol = solve_nlp(
            what,
            x,
            cost,
            ca.vertcat(*self._g),
            x0=self._pack(*guess),
            lbx=self._pack(*lower),
            ubx=self._pack(*upper),
            lbg=np.asarray(self._lbg, float),
            ubg=np.asarray(self._ubg, float),
            cfg=cfg,
        )
        s_n = self.seg_t.shape[0]
        body = sol.x[s_n:]
        stride = self.nx + self.nu
        head = body[: stride * k].reshape(k, stride)
        states = np.vstack([head[:, : self.nx], body[stride * k :][None, :]])
        return sol, sol.x[:s_n], states, head[:, self.nx :]
