"""Gate windows, track bounds and the node layout shared by the point-mass and full-model planners.

A gate passage is a *waypoint constraint with a tolerance inside the opening*: the node at the end of
segment ``i`` lies in passage ``i``'s gate plane (gate-frame x = 0), its crossing point lies within the
opening shrunk by ``tol`` on every side (|y|, |z| <= size/2 − tol in the gate frame), and the velocity
points through the gate (n·v >= ``MIN_CROSS_SPEED``), as the race rules require (x < 0 -> x >= 0).

A single node in the plane does not stop an oblique crossing from clipping a bar with the drone's
sphere, so the straight line through the crossing point along the velocity must also keep ``tol``
from the edge over the slab |x| <= frame_width/2 + radius, where the sphere could touch the bars
(checked at both faces of the slab; the line is linear in x, so the whole slab follows). Over those
few tens of centimetres the flown path departs from that line by millimetres.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from icarus_vision.planning.result import PlanError
from icarus_vision.sim.quad import QuadParams
from icarus_vision.sim.track import Track

MIN_CROSS_SPEED = 0.1  # m/s along the gate normal at the passage node
TOL_CLEARANCE = 0.05  # m of clearance added to the drone radius by the default tolerance


def default_tol(quad: QuadParams) -> float:
    """Default margin kept from the opening's inner edge: the collision radius plus 5 cm."""
    return quad.radius + TOL_CLEARANCE


@dataclass(frozen=True)
class Layout:
    """Gate passages, node layout and position bounds of one planning problem.

    Attributes:
        centres: (S, 3) world gate centres of the S passages (all laps), m.
        normals: (S, 3) world passage directions (gate-frame x).
        laterals: (S, 3) world gate-frame y axes (left).
        half_windows: (S,) allowed |y|, |z| of the crossing point in the gate frame, m.
        slab: (S,) half-depth of the slab around the gate plane kept inside the window, m.
        nodes_per_gate: intervals per segment; segment i ends at node (i + 1) * nodes_per_gate.
        start: (3,) start position, m.
        start_yaw: start heading, rad.
        pos_lo: (3,) lower position bound of the drone's centre (track bounds + radius), m.
        pos_hi: (3,) upper position bound, m.
    """

    centres: np.ndarray
    normals: np.ndarray
    laterals: np.ndarray
    half_windows: np.ndarray
    slab: np.ndarray
    nodes_per_gate: int
    start: np.ndarray
    start_yaw: float
    pos_lo: np.ndarray
    pos_hi: np.ndarray

    @property
    def num_segments(self) -> int:
        return len(self.centres)

    @property
    def num_intervals(self) -> int:
        return self.num_segments * self.nodes_per_gate

    @property
    def gate_nodes(self) -> np.ndarray:
        """(S,) int index of the node at which each passage is made."""
        return (np.arange(self.num_segments) + 1) * self.nodes_per_gate

    def segment_of_interval(self) -> np.ndarray:
        """(K,) int segment index of every interval."""
        return np.repeat(np.arange(self.num_segments), self.nodes_per_gate)

    def gate_frame(self, i: int, pos):
        """Gate-frame coordinates (x, y, z) of ``pos`` relative to passage ``i`` (numpy or CasADi)."""
        c, n, lat = self.centres[i], self.normals[i], self.laterals[i]
        d = [pos[j] - c[j] for j in range(3)]
        gx = n[0] * d[0] + n[1] * d[1]
        gy = lat[0] * d[0] + lat[1] * d[1]
        return gx, gy, d[2]

    def passage_constraints(self, i: int, pos, vel) -> list[tuple]:
        """Constraints ``(expr, lo, hi)`` of passage ``i`` on the passage node's pos, vel (3,) each.

        Works on numpy arrays and CasADi expressions alike (scalar expressions).
        """
        gx, gy, gz = self.gate_frame(i, pos)
        n, lat = self.normals[i], self.laterals[i]
        vn = n[0] * vel[0] + n[1] * vel[1]
        vy = lat[0] * vel[0] + lat[1] * vel[1]
        w, depth = self.half_windows[i], self.slab[i]
        out = [(gx, 0.0, 0.0), (gy, -w, w), (gz, -w, w), (vn, MIN_CROSS_SPEED, np.inf)]
        for s in (-depth, depth):  # the velocity line at the slab faces, multiplied by vn > 0
            for lateral, v_lat in ((gy, vy), (gz, vel[2])):
                out.append((lateral * vn + s * v_lat - w * vn, -np.inf, 0.0))
                out.append((lateral * vn + s * v_lat + w * vn, 0.0, np.inf))
        return out


def build_layout(track: Track, quad: QuadParams, nodes_per_gate: int, tol: float) -> Layout:
    """Gate windows and bounds of ``track`` for ``quad``; PlanError when a window cannot be reached.

    Raises:
        ValueError: ``nodes_per_gate`` < 2 or a negative ``tol``.
        PlanError: status ``Presolve_Infeasible`` when a gate's window is empty (tol >= size/2) or
            lies wholly outside the track bounds (shrunk by the drone radius).
    """
    if int(nodes_per_gate) != nodes_per_gate or nodes_per_gate < 2:
        raise ValueError(f"nodes_per_gate must be an integer >= 2, got {nodes_per_gate!r}")
    if not math.isfinite(tol) or tol < 0:
        raise ValueError(f"tol must be a finite margin >= 0 m, got {tol!r}")
    passages = track.passages
    yaws = np.array([g.yaw for g in passages])
    normals = np.stack([np.cos(yaws), np.sin(yaws), np.zeros_like(yaws)], axis=1)
    laterals = np.stack([-np.sin(yaws), np.cos(yaws), np.zeros_like(yaws)], axis=1)
    centres = np.array([g.pos for g in passages], float)
    half = np.array([g.size / 2.0 - tol for g in passages])
    start = np.array(track.start_pos, float)
    lo = np.array(track.bounds_min, float) + quad.radius
    hi = np.array(track.bounds_max, float) - quad.radius
    lo = np.minimum(lo, start)  # a start resting below the radius margin stays admissible
    hi = np.maximum(hi, start)
    layout = Layout(
        centres=centres,
        normals=normals,
        laterals=laterals,
        half_windows=half,
        slab=np.array([g.frame_width / 2.0 + quad.radius for g in passages]),
        nodes_per_gate=int(nodes_per_gate),
        start=start,
        start_yaw=math.radians(track.start_yaw_deg),
        pos_lo=lo,
        pos_hi=hi,
    )
    _presolve(layout, track)
    return layout


def _presolve(layout: Layout, track: Track) -> None:
    """Refuse passages whose tolerance window is empty or outside the bounds, naming the gate."""
    n_gates = len(track.gates)
    for i in range(layout.num_segments):
        gate = i % n_gates
        w = layout.half_windows[i]
        if w <= 0:
            size = track.gates[gate].size
            raise PlanError(
                "Presolve_Infeasible",
                f"gate {gate}: tolerance leaves no window inside the {size} m opening "
                f"(tol must be < {size / 2} m)",
            )
        c, lat = layout.centres[i], layout.laterals[i]
        s = np.linspace(-w, w, 41)[:, None]
        pts = c + s * lat
        z_ok = c[2] - w <= layout.pos_hi[2] and c[2] + w >= layout.pos_lo[2]
        xy_ok = np.any(
            np.all((pts[:, :2] >= layout.pos_lo[:2]) & (pts[:, :2] <= layout.pos_hi[:2]), axis=1)
        )
        if not (z_ok and xy_ok):
            raise PlanError(
                "Presolve_Infeasible",
                f"gate {gate}: its window (opening minus tolerance) lies outside the track bounds "
                f"shrunk by the drone radius ({layout.pos_lo.round(2).tolist()} .. "
                f"{layout.pos_hi.round(2).tolist()})",
            )


def waypoint_polyline(layout: Layout) -> np.ndarray:
    """(S + 1, 3) start followed by every passage centre."""
    return np.vstack([layout.start, layout.centres])


def thrust_accel_limit(quad: QuadParams) -> float:
    """Maximum specific thrust T_max / m, m/s²."""
    return quad.thrust_max / quad.mass
