"""Planner solve time: the 7-gate ``grand-prix`` (target <= 60 s) and the 10-gate ``ten-gates`` (<= 120 s).

Run on a quiet machine: ``.venv/bin/python benchmarks/plan_time.py [--repeats 3] [--json PATH]``.
One core (the process is pinned to one CPU, BLAS threads set to 1), no cache. The time is the wall
time of ``plan`` (problem construction, point-mass bound, point-mass guess and full-model solve);
the median over repeats is reported with the lap times and IPOPT iterations.
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("MKL_NUM_THREADS", "1")

from icarus_vision.fileio import atomic_write_json  # noqa: E402
from icarus_vision.planning import plan  # noqa: E402
from icarus_vision.sim.builtin import builtin_track  # noqa: E402
from icarus_vision.sim.quad import QuadParams  # noqa: E402

TARGETS_S = {"grand-prix": 60.0, "ten-gates": 120.0}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--nodes-per-gate", type=int, default=20)
    ap.add_argument("--json", type=str, default=None)
    args = ap.parse_args()
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {sorted(os.sched_getaffinity(0))[0]})  # one core
    quad = QuadParams()
    rows = []
    for name, target in TARGETS_S.items():
        track = builtin_track(name)
        runs = [
            plan(track, quad, nodes_per_gate=args.nodes_per_gate, cache_dir=None)
            for _ in range(args.repeats)
        ]
        r = runs[0]
        row = {
            "track": name,
            "gates": track.num_passages,
            "nodes_per_gate": args.nodes_per_gate,
            "solve_time_s": round(statistics.median(x.solve_time_s for x in runs), 2),
            "solve_times_s": [round(x.solve_time_s, 2) for x in runs],
            "target_s": target,
            "time_optimal_s": round(r.time_optimal_s, 3),
            "point_mass_s": round(r.point_mass_s, 3),
            "iterations": r.iterations,
            "solver_status": r.solver_status,
        }
        rows.append(row)
        ok = "ok" if row["solve_time_s"] <= target else "OVER TARGET"
        print(
            f"{name:11s} {row['gates']:2d} gates  solve {row['solve_time_s']:6.2f} s "
            f"(target {target:.0f} s, {ok})  lap {row['time_optimal_s']:.3f} s  "
            f"point mass {row['point_mass_s']:.3f} s  {row['iterations']} it  {row['solver_status']}"
        )
    if args.json:
        atomic_write_json(
            args.json,
            {
                "benchmark": "plan_time",
                "machine": platform.processor() or platform.machine(),
                "results": rows,
            },
        )


if __name__ == "__main__":
    main()
