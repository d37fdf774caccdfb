"""The race figures of the README: real-time factor, finish rates, cnn vs oracle lap time.

    .venv/bin/python benchmarks/race_targets.py [--detector cnn] [--seeds 20] [--tracks 20] [--json PATH]

* real-time factor of `race` (no video) on the default track at the default 320x240 camera;
* the default track with randomisation (mass, wind, gate jitter): share of seeds that finish;
* random 10-gate tracks (one per seed, randomisation on): share that finish;
* lap time with the detector against the same policy with the oracle on the default track.
Every race is the whole loop: PyBullet physics, rendering, detector, estimator, shipped policy.
"""

from __future__ import annotations

import argparse
import json
import statistics

from icarus_vision.fileio import atomic_write_json
from icarus_vision.racing.runner import run_race
from icarus_vision.sim.random_track import random_track


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--detector", default="cnn")
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--tracks", type=int, default=20)
    ap.add_argument(
        "--seed0", type=int, default=100, help="first seed (the estimator was tuned on 0-19)"
    )
    ap.add_argument("--json", default=None)
    args = ap.parse_args()
    det = args.detector

    s0 = args.seed0
    plain = [run_race(None, detector=det, seed=s).report for s in range(s0, s0 + 3)]
    oracle = [run_race(None, detector="oracle", seed=s).report for s in range(s0, s0 + 3)]
    rand_default = [
        run_race(None, detector=det, seed=s, randomize=True).report
        for s in range(s0, s0 + args.seeds)
    ]
    rand_tracks = [
        run_race(random_track(10, 1000 + s), detector=det, seed=s, randomize=True).report
        for s in range(s0, s0 + args.tracks)
    ]

    def finished(rs):
        return sum(r["finished"] for r in rs) / len(rs)

    def failures(rs):
        return [(r["seed"], r["crash_reason"], r["gates_passed"]) for r in rs if not r["finished"]]

    lap = [r["total_time_s"] for r in plain if r["finished"]]
    lap_oracle = [r["total_time_s"] for r in oracle if r["finished"]]
    out = {
        "detector": det,
        "realtime_factor": statistics.median(r["realtime_factor"] for r in plain),
        "default_track_lap_s": statistics.median(lap) if lap else None,
        "default_track_lap_oracle_s": statistics.median(lap_oracle) if lap_oracle else None,
        "lap_ratio_vs_oracle": round(statistics.median(lap) / statistics.median(lap_oracle), 4)
        if lap and lap_oracle
        else None,
        "default_randomized_finish_rate": finished(rand_default),
        "default_randomized_failures": failures(rand_default),
        "random10_finish_rate": finished(rand_tracks),
        "random10_failures": failures(rand_tracks),
        "detection_rate_median": statistics.median(
            r["perception"]["detection_rate"] for r in rand_default + rand_tracks
        ),
        "rel_gate_error_median_m": statistics.median(
            r["perception"]["rel_gate_error_m"]["median"] for r in rand_default + rand_tracks
        ),
    }
    print(json.dumps(out, indent=2))
    if args.json:
        atomic_write_json(args.json, out)


if __name__ == "__main__":
    main()
