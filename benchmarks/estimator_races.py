"""The estimator on the race loop's layouts, every variant on the same flight and the same images.

    .venv/bin/python benchmarks/estimator_races.py [--tracks 140] [--detector cnn]
        [--policy default] [--workers 2] [--json PATH]

The layouts, seeds and randomisation of ``race_policy.py vision`` (``race_track(10, 3000 + i)``,
seed 100 + i, randomised, gates-v1 looks), flown open loop: the pilot reads the truth (the
oracle's flight, step for step) while camera, detector and estimator run alongside. A change of the
estimator or the detector then changes nothing but its own figures, where the closed loop turns
any change into a different flight. Figures, over every camera frame of every layout: how often
the estimator's next gate is not the true one; the error of the next gate's relative position
within 5 m (median, p95, frames whose next gate is the true one); within 3 m, the share of frames
more than 0.2 m and 0.3 m off, and how many layouts have such a frame.
"""

from __future__ import annotations

import argparse
import time
from concurrent.futures import ProcessPoolExecutor

import numpy as np
from race_policy import vision_race  # benchmarks/, on the path when run as a script

from icarus_vision.fileio import atomic_write_json


def fly(i: int, detector: str, policy: str) -> dict:
    res = vision_race(i, detector, policy, open_loop=True)
    rec = res.loop
    return {"dist": rec.gate_dist, "err": rec.rel_err, "ok": rec.target_ok,
            "finished": res.report["finished"]}  # fmt: skip


def summarise(flights: list[dict]) -> dict:
    dist = np.concatenate([f["dist"] for f in flights])
    err = np.concatenate([f["err"] for f in flights])
    ok = np.concatenate([f["ok"] for f in flights]).astype(bool)
    near, close = ok & (dist < 5.0), ok & (dist < 3.0)
    bad = [bool(np.any((np.array(f["err"]) > 0.3) & (np.array(f["dist"]) < 3.0) & np.array(f["ok"], bool)))
           for f in flights]  # fmt: skip
    return {
        "layouts": len(flights),
        "finished_on_truth": sum(f["finished"] for f in flights),
        "frames": int(len(err)),
        "wrong_next_gate_pct": round(100 * float(np.mean(~ok)), 2),
        "within_5m_median_m": round(float(np.median(err[near])), 4),
        "within_5m_p95_m": round(float(np.percentile(err[near], 95)), 4),
        "within_3m_over_0.2m_pct": round(100 * float(np.mean(err[close] > 0.2)), 2),
        "within_3m_over_0.3m_pct": round(100 * float(np.mean(err[close] > 0.3)), 2),
        "layouts_with_a_frame_over_0.3m_within_3m": int(sum(bad)),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--tracks", type=int, default=140)
    ap.add_argument("--detector", default="cnn")
    ap.add_argument("--policy", default="default")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--json", default=None)
    args = ap.parse_args()
    if args.tracks < 1 or args.workers < 1:
        ap.error("--tracks and --workers must be >= 1")
    t0 = time.perf_counter()
    with ProcessPoolExecutor(args.workers) as pool:
        flights = list(pool.map(fly, range(args.tracks), [args.detector] * args.tracks,
                                [args.policy] * args.tracks))  # fmt: skip
    out = {**summarise(flights), "detector": args.detector, "policy": args.policy,
           "wall_s": round(time.perf_counter() - t0, 1)}  # fmt: skip
    for k, v in out.items():
        print(f"{k}: {v}")
    if args.json:
        atomic_write_json(args.json, out)


if __name__ == "__main__":
    main()
