"""Our planner on the public example set-up of Foehn et al. (2021), for docs/planning.md.

Usage: ``.venv/bin/python benchmarks/plan_cpc_track.py [--nodes-per-gate 15] [--json PATH]``.

Set-up transcribed from the authors' public example (github.com/uzh-rpg/rpg_time_optimal,
``tracks/track.yaml`` and ``quads/quad.yaml``): 19 waypoints (the 7-waypoint split-S lap flown
three times, the third lap cut after its 5th waypoint) and an end point, start at rest at
(-5, 4.5, 1.2), waypoint tolerance 0.3 m, z >= 0.5 m; a 0.85 kg quadrotor with thrust-to-weight
3.3, body rates within 15 rad/s (roll, pitch) and 0.3 rad/s (yaw), no drag.

Differences that remain (see docs/planning.md): their waypoints are 0.3 m balls with no direction,
ours are gate windows (±0.3 m squares in a vertical plane) with a passage direction, so the heading
of each window is iterated from the previous solution's velocity; their model has single-rotor
thrust inputs and rigid-body rotational dynamics, ours collective thrust and body-rate commands with
a 10 ms lag; their example also ramps the thrust and rate limits up over the first 35 m, which we
leave out.
"""

from __future__ import annotations

import argparse
import math
import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from icarus_vision.fileio import atomic_write_json  # noqa: E402
from icarus_vision.planning import plan  # noqa: E402
from icarus_vision.sim.quad import QuadParams  # noqa: E402
from icarus_vision.sim.track import Gate, Track  # noqa: E402

LAP = [
    (-1.1, -1.6, 3.6),
    (9.2, 6.6, 1.0),
    (9.2, -4.0, 1.2),
    (-4.5, -6.0, 3.5),
    (-4.5, -6.0, 0.8),
    (4.75, -0.9, 1.2),
    (-2.8, 6.8, 1.2),
]
WAYPOINTS = LAP + LAP + LAP[:5] + [(4.75, -0.9, 1.2)]  # 19 waypoints + the end point
START = (-5.0, 4.5, 1.2)
TOLERANCE = 0.3
QUAD = QuadParams(
    name="cpc-example",
    mass=0.85,
    inertia=(0.001, 0.001, 0.0017),
    arm_length=0.15,
    thrust_to_weight=3.3,
    max_rate=(15.0, 15.0, 0.3),
    motor_tau=0.01,
    drag=(0.0, 0.0, 0.0),
    radius=0.01,
)


def make_track(yaws_deg: list[float]) -> Track:
    """Waypoints as ±0.3 m windows (tol 0) facing ``yaws_deg``; z >= 0.5 m, no other bound."""
    gates = tuple(
        Gate(pos=p, yaw_deg=y, size=2 * TOLERANCE, frame_width=0.01)
        for p, y in zip(WAYPOINTS, yaws_deg, strict=True)
    )
    return Track(
        name="cpc-split-s",
        gates=gates,
        start_pos=START,
        bounds_min=(-50.0, -50.0, 0.5 - QUAD.radius),
        bounds_max=(50.0, 50.0, 50.0),
    )


def polyline_yaws() -> list[float]:
    """Initial window headings: the bisector of the incoming and outgoing polyline directions."""
    pts = np.array([START, *WAYPOINTS])
    out = []
    for i in range(1, len(pts)):
        d = pts[i] - pts[i - 1]
        if i + 1 < len(pts):
            d = d / np.linalg.norm(d) + (pts[i + 1] - pts[i]) / np.linalg.norm(pts[i + 1] - pts[i])
        out.append(math.degrees(math.atan2(d[1], d[0])))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--nodes-per-gate", type=int, default=15)
    ap.add_argument("--iterations", type=int, default=4)
    ap.add_argument("--json", type=str, default=None)
    args = ap.parse_args()
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {sorted(os.sched_getaffinity(0))[0]})  # one core
    yaws = polyline_yaws()
    history = []
    for it in range(args.iterations):
        r = plan(
            make_track(yaws), QUAD, nodes_per_gate=args.nodes_per_gate, tol=0.0, cache_dir=None
        )
        v = r.vel[r.gate_nodes]
        new = [math.degrees(math.atan2(vy, vx)) for vx, vy in v[:, :2]]
        change = max(abs((a - b + 180) % 360 - 180) for a, b in zip(new, yaws, strict=True))
        history.append(
            {
                "iteration": it,
                "time_optimal_s": round(r.time_optimal_s, 3),
                "point_mass_s": round(r.point_mass_s, 3),
                "solve_time_s": round(r.solve_time_s, 1),
                "max_heading_change_deg": round(change, 1),
            }
        )
        print(history[-1], flush=True)
        yaws = new
        if change < 2.0:
            break
    result = {
        "track": "rpg_time_optimal example (split-S, 19 waypoints + end)",
        "nodes_per_gate": args.nodes_per_gate,
        "time_optimal_s": history[-1]["time_optimal_s"],
        "point_mass_s": history[-1]["point_mass_s"],
        "max_speed_mps": round(float(r.speed.max()), 2),
        "iterations": history,
    }
    print(result)
    if args.json:
        atomic_write_json(args.json, result)


if __name__ == "__main__":
    main()
