"""How close to the time-optimal lap a policy flies, and how often it finishes, on race layouts.

    .venv/bin/python benchmarks/policy_speed.py [--policy default] [--tracks 20] [--seed0 2000]
        [--gates 10] [--difficulty 1.0] [--finish-episodes 300] [--plan-only] [--lookahead]
        [--lookahead-race]
        [--json PATH]

Lap ratio: draws ``race_track(gates, seed, difficulty)`` for seeds from ``--seed0`` until
``--tracks`` of them have a time-optimal plan (plans are solved once and cached under
``runs/plans/``, as `plan` does; a track the planner cannot solve is listed and skipped), then flies
the policy once on each planned track with ground truth and the nominal quadrotor (the plan's own
model; no randomisation) and reports lap / time-optimal per track and the median over the tracks the
policy finished, with where the time goes: the policy's path length over the plan's
(``path_ratio``) and its mean speed over the plan's (``speed_ratio``; lap ratio = path ratio /
speed ratio). ``--plan-only`` fills the cache and stops.

Finish rate: the policy on ``--finish-episodes`` random race layouts of the same distribution
(seed 5000 on), ground truth, randomisation on (mass ±20 %, thrust ±10 %, wind, gusts, gate jitter).

``--lookahead`` flies both through the look-ahead safety filter (``eval-policy --lookahead``),
``--lookahead-race`` through the filter's racing mode (``eval-policy --lookahead-race``).
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from icarus_vision.planning.planner import plan
from icarus_vision.planning.result import PlanError
from icarus_vision.policy.evaluate import evaluate_policy
from icarus_vision.policy.lookahead import racing
from icarus_vision.policy.pilots import resolve_policy
from icarus_vision.sim.race_layouts import race_track


def planned_tracks(n: int, seed0: int, gates: int, difficulty: float) -> tuple[list, list[int]]:
    """(seed, track, plan time, plan path length) for the first ``n`` seeds from ``seed0`` whose
    plan solves; failed seeds."""
    out, failed, seed = [], [], seed0
    while len(out) < n:
        track = race_track(gates, seed, difficulty=difficulty)
        t0 = time.perf_counter()
        try:
            result = plan(track)
            path = float(np.linalg.norm(np.diff(result.pos, axis=0), axis=1).sum())
            out.append((seed, track, result.time_optimal_s, path))
            print(
                f"seed {seed}: plan {result.time_optimal_s:.3f} s ({time.perf_counter() - t0:.0f} s)",
                flush=True,
            )
        except PlanError as e:
            failed.append(seed)
            print(f"seed {seed}: no plan ({e.status})", flush=True)
        seed += 1
    return out, failed


def _median(values: list[float]) -> float | None:
    return round(float(np.median(values)), 4) if values else None


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--policy", default="default")
    ap.add_argument("--tracks", type=int, default=20)
    ap.add_argument("--seed0", type=int, default=2000)
    ap.add_argument("--gates", type=int, default=10)
    ap.add_argument("--difficulty", type=float, default=1.0)
    ap.add_argument("--finish-episodes", type=int, default=300)
    ap.add_argument("--plan-only", action="store_true")
    ap.add_argument("--lookahead", action="store_true", help="through the look-ahead filter")
    ap.add_argument("--lookahead-race", action="store_true", help="the filter's racing mode")
    ap.add_argument("--json", default=None)
    args = ap.parse_args()

    planned, failed = planned_tracks(args.tracks, args.seed0, args.gates, args.difficulty)
    if args.plan_only:
        return
    pol = resolve_policy(args.policy)
    filt = racing() if args.lookahead_race else args.lookahead
    rows = []
    for seed, track, best, plan_path in planned:
        r = evaluate_policy(pol, track, episodes=1, randomize=False, seed=0, lookahead=filt)
        lap, speed = r["lap_time_s"]["median"], r["mean_speed_mps"]
        rows.append({"seed": seed, "time_optimal_s": round(best, 4), "finished": r["success_rate"] == 1.0,
                     "lap_s": lap, "ratio": None if lap is None else round(lap / best, 4),
                     "path_ratio": None if lap is None else round(speed * lap / plan_path, 4),
                     "speed_ratio": round(speed * best / plan_path, 4)})  # fmt: skip
        print(rows[-1], flush=True)
    ratios = [r["ratio"] for r in rows if r["ratio"] is not None]
    finish = evaluate_policy(pol, None, episodes=args.finish_episodes, num_gates=args.gates,
                             randomize=True, seed=5000, difficulty=args.difficulty,
                             lookahead=filt)  # fmt: skip
    summary = {
        "policy": pol.name,
        "lookahead": bool(filt),
        "lookahead_race": args.lookahead_race,
        "difficulty": args.difficulty,
        "planned_tracks": len(planned),
        "plan_failures": failed,
        "finished_planned": len(ratios),
        "median_ratio": round(float(np.median(ratios)), 4) if ratios else None,
        "ratio_p10_p90": [round(float(np.percentile(ratios, q)), 4) for q in (10, 90)]
        if ratios
        else None,
        "median_path_ratio": _median([r["path_ratio"] for r in rows if r["ratio"] is not None]),
        "median_speed_ratio": _median([r["speed_ratio"] for r in rows if r["ratio"] is not None]),
        "finish_rate_randomised": finish["success_rate"],
        "finish_episodes": finish["episodes"],
        "crash_reasons": finish["crash_reasons"],
        "rows": rows,
    }
    print(json.dumps({k: v for k, v in summary.items() if k != "rows"}, indent=1))
    if args.json:
        with open(args.json, "w") as f:
            json.dump(summary, f, indent=1)


if __name__ == "__main__":
    main()
