"""Relative gate pose estimator: error on the 10-gate track with a detector in the loop, and cost.

Usage: ``.venv/bin/python benchmarks/estimator.py [--detector oracle|cnn|opencv] [--seeds 0 1 2]
[--pixel-noise 0.75] [--no-render] [--json PATH]``.

Error: the scripted pilot flies ``ten-gates`` in PyBullet on the estimate (closed loop), the camera
renders at its rate (30 Hz) and the detector runs on it: ``cnn`` is the shipped network, with the
estimator set up for it by ``config_for_detector``; ``oracle`` reports the projected true corners of
the gates visible in the segmentation mask with Gaussian pixel noise (σ = ``--pixel-noise``).
Odometry has its default noise and drift, and the prior map is displaced by 0.3 m (σ).
Figures: median and 95th percentile of the relative-position error, over all camera frames and
within 5 m of the gate, per seed, their means, and how many seeds meet the issue's targets.

Cost: the estimator's inputs of one flight are recorded and replayed through a fresh estimator on
one thread; the figure is the mean time of ``update`` (one camera frame: every detection checked,
solved, associated and fused), best of ``--repeats`` replays.
"""

from __future__ import annotations

import argparse
import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import time  # noqa: E402

import cv2  # noqa: E402
import numpy as np  # noqa: E402

from icarus_vision.estimator import GateEstimator  # noqa: E402
from icarus_vision.estimator.config import config_for_detector  # noqa: E402
from icarus_vision.estimator.evaluate import evaluate_estimator  # noqa: E402
from icarus_vision.fileio import atomic_write_json  # noqa: E402
from icarus_vision.render.camera import Camera  # noqa: E402
from icarus_vision.sim.quad import QuadParams  # noqa: E402


def replay_cost(record: list, repeats: int, detector: str = "oracle") -> dict:
    """Best-of-``repeats`` mean time of update() and predict() replaying a recorded flight."""
    camera = Camera.from_params(QuadParams().camera)
    prior = record[0][1]
    best_u, best_p, per_frame = np.inf, np.inf, None
    for _ in range(repeats):
        est = GateEstimator(camera, config_for_detector(detector.split(":")[0]), prior)
        tu, tp = [], []
        for kind, od, dets in record[1:]:
            t0 = time.perf_counter()
            if kind == "update":
                est.update(od, dets)
                tu.append(time.perf_counter() - t0)
            else:
                est.predict(od)
                tp.append(time.perf_counter() - t0)
        if np.mean(tu) < best_u:
            best_u, per_frame = float(np.mean(tu)), np.array(tu)
        best_p = min(best_p, float(np.mean(tp)))
    n_det = [len(d) for k, _, d in record[1:] if k == "update"]
    return {
        "ms_per_frame": round(1e3 * best_u, 4),
        "ms_per_frame_median": round(1e3 * float(np.median(per_frame)), 4),
        "ms_per_frame_p95": round(1e3 * float(np.percentile(per_frame, 95)), 4),
        "ms_per_predict": round(1e3 * best_p, 4),
        "detections_per_frame": round(float(np.mean(n_det)), 3),
        "frames": len(per_frame),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--track", default="ten-gates")
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    ap.add_argument("--detector", default="oracle", help="oracle, opencv or cnn[:PATH]")
    ap.add_argument("--pixel-noise", type=float, default=0.75, help="oracle only")
    ap.add_argument("--map-error", type=float, default=0.3)
    ap.add_argument("--no-render", action="store_true", help="oracle visibility from geometry")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--json", default=None)
    args = ap.parse_args()
    cv2.setNumThreads(1)

    runs = []
    record: list = []
    for i, seed in enumerate(args.seeds):
        r = evaluate_estimator(
            args.track, args.detector, seed, pixel_noise=args.pixel_noise, map_error_m=args.map_error,
            render=not args.no_render, record=record if i == 0 else None,
        )  # fmt: skip
        runs.append(r)
        print(
            f"seed {seed}: frames {r['frames']}, detection rate {r['detection_rate']:.3f}, "
            f"error median {r['rel_gate_error_m']['median']} p95 {r['rel_gate_error_m']['p95']} m, "
            f"within 5 m median {r['within_5m']['median']} p95 {r['within_5m']['p95']} m, "
            f"gates {r['gates_passed']}/{r['gates_total']}, in-loop cost {r['ms_per_frame']} ms"
        )
    cost = replay_cost(record, args.repeats, args.detector)
    print(
        f"estimator cost (replay, 1 thread): {cost['ms_per_frame']} ms/frame "
        f"(median {cost['ms_per_frame_median']}, p95 {cost['ms_per_frame_p95']}), "
        f"{cost['detections_per_frame']} detections/frame; predict {cost['ms_per_predict']} ms"
    )
    pooled5 = np.array([r["within_5m"]["median"] for r in runs])
    out = {
        "track": args.track,
        "detector": args.detector,
        "pixel_noise_px": args.pixel_noise if args.detector == "oracle" else None,
        "map_error_m": args.map_error,
        "rendered": not args.no_render,
        "runs": runs,
        "within_5m_median_mean": round(float(pooled5.mean()), 4),
        "within_5m_p95_mean": round(float(np.mean([r["within_5m"]["p95"] for r in runs])), 4),
        "rel_gate_error_median_mean": round(
            float(np.mean([r["rel_gate_error_m"]["median"] for r in runs])), 4
        ),
        "rel_gate_error_p95_mean": round(
            float(np.mean([r["rel_gate_error_m"]["p95"] for r in runs])), 4
        ),
        "within_5m_p95_max": max(r["within_5m"]["p95"] for r in runs),
        "seeds_meeting_targets": sum(
            r["within_5m"]["median"] <= 0.10 and r["within_5m"]["p95"] <= 0.30 for r in runs
        ),
        "cost": cost,
    }
    print(
        f"mean over seeds: within 5 m median {out['within_5m_median_mean']} m, "
        f"p95 {out['within_5m_p95_mean']} m; overall median {out['rel_gate_error_median_mean']} m, "
        f"p95 {out['rel_gate_error_p95_mean']} m; {out['seeds_meeting_targets']}/{len(runs)} seeds "
        f"within 5 m meet median <= 0.10 m and p95 <= 0.30 m"
    )
    if args.json:
        atomic_write_json(args.json, out)


if __name__ == "__main__":
    main()
