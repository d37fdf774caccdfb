"""The planner's result type and its error."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


class PlanError(RuntimeError):
    """Planning failed or the problem is infeasible; ``status`` is the solver's (or presolve's) status.

    Attributes:
        status: IPOPT return status (e.g. ``Infeasible_Problem_Detected``,
            ``Maximum_Iterations_Exceeded``) or ``Presolve_Infeasible`` / ``Verification_Failed``.
    """

    def __init__(self, status: str, message: str) -> None:
        super().__init__(f"planning failed [{status}]: {message}")
        self.status = status


@dataclass(frozen=True, eq=False)
class PlanResult:
    """A minimum-time trajectory through every gate passage of a track (all laps).

    Nodes k = 0..K; interval k runs from ``t[k]`` to ``t[k + 1]`` with the commands held constant.
    Frames: world z up; body FLU; quaternions x, y, z, w (body -> world), as in ``sim.dynamics``.
    """

    track: str
    """Track name."""
    quad: str
    """Quadrotor name."""
    laps: int
    """Laps flown (every gate passage of every lap is in the plan)."""
    time_optimal_s: float
    """Minimum time of the full quadrotor model from rest at the start to the last passage, s."""
    point_mass_s: float
    """Point-mass minimum time for the same passages (a lower bound, see ``point_mass``), s."""
    solver_status: str
    """IPOPT return status of the full-model solve."""
    solve_time_s: float
    """Wall time of the point-mass and full-model solves together, s."""
    success: bool
    """True when IPOPT converged and the trajectory passed the post-solve checks."""
    iterations: int
    """IPOPT iterations of the full-model solve."""
    nodes_per_gate: int
    """Shooting intervals per gate segment."""
    tol: float
    """Margin kept from the opening's inner edge at each passage, m."""
    bar_contact_s: float
    """Time the replayed plan's collision sphere touches a gate bar, s (0 for a clean plan). Only
    the passage itself is constrained; see docs/planning.md (Limitations)."""
    t: np.ndarray = field(repr=False)
    """(K + 1,) node times, s."""
    pos: np.ndarray = field(repr=False)
    """(K + 1, 3) world position, m."""
    vel: np.ndarray = field(repr=False)
    """(K + 1, 3) world velocity, m/s."""
    quat: np.ndarray = field(repr=False)
    """(K + 1, 4) attitude x, y, z, w."""
    thrust: np.ndarray = field(repr=False)
    """(K + 1,) actual collective thrust (lag state), N."""
    rates: np.ndarray = field(repr=False)
    """(K + 1, 3) actual body rates (lag state), rad/s."""
    thrust_cmd: np.ndarray = field(repr=False)
    """(K,) commanded collective thrust on each interval, N, within [0, T_max]."""
    rate_cmd: np.ndarray = field(repr=False)
    """(K, 3) commanded body rates on each interval, rad/s, within ±max_rate."""
    gate_nodes: np.ndarray = field(repr=False)
    """(S,) node index of each gate passage, in racing order."""

    @property
    def speed(self) -> np.ndarray:
        """(K + 1,) speed, m/s."""
        return np.linalg.norm(self.vel, axis=1)

    def passage_paths(self) -> list[np.ndarray]:
        """The planned path to each passage: element k (M + 1, 3) the node positions from passage
        k − 1 (or the start) to passage k, for a ``path`` reward (``RaceCore.set_reference``)."""
        ends = [0, *(int(k) for k in self.gate_nodes)]
        return [self.pos[a : b + 1].copy() for a, b in zip(ends[:-1], ends[1:], strict=True)]

    @property
    def ratio_to_point_mass(self) -> float:
        """time_optimal_s / point_mass_s (>= 1 up to discretisation)."""
        return self.time_optimal_s / self.point_mass_s

    def summary(self) -> dict:
        """The machine-readable fields of ``plan --json`` (ARCHITECTURE.md)."""
        return {
            "track": self.track,
            "quad": self.quad,
            "laps": self.laps,
            "time_optimal_s": round(self.time_optimal_s, 4),
            "point_mass_s": round(self.point_mass_s, 4),
            "solver_status": self.solver_status,
            "solve_time_s": round(self.solve_time_s, 3),
            "success": self.success,
            "iterations": self.iterations,
            "nodes_per_gate": self.nodes_per_gate,
            "tol_m": self.tol,
            "bar_contact_s": round(self.bar_contact_s, 3),
        }
