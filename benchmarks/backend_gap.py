"""The sim-to-sim gap: the shipped policies on the batched, PyBullet and MuJoCo backends, ground truth.

    .venv/bin/python benchmarks/backend_gap.py [--episodes 300] [--seeds 20] [--policy auto]
        [--json PATH]

``random``: the generalist (``default``) on ``--episodes`` random race layouts
(``race_track(10, seed, difficulty=1)``, the racing issue's distribution), domain randomisation on
(mass, thrust, wind, gate jitter), the same seeds on every backend: finish rate and median lap.
``builtin``: every built-in track with ``--policy auto`` (the track's shipped specialist where there
is one, else the generalist), randomised, ``--seeds`` episodes each: finish rate and median lap.
Ground truth means the observation carries the true next-gate position (eval-policy); the camera
and detector in the loop are ``race_policy.py builtin --backend mujoco``. Each backend's
difference from PyBullet (the backend the policies are flown on in ``race``) is printed in points.
``--policy NAME|PATH`` flies that policy everywhere instead (random layouts and every track).
"""

from __future__ import annotations

import argparse
import json
import time

from icarus_vision.fileio import atomic_write_json
from icarus_vision.policy.evaluate import evaluate_policy
from icarus_vision.policy.pilots import resolve_policy
from icarus_vision.sim.builtin import BUILTIN_TRACKS, resolve_track

BACKENDS = ("batched", "pybullet", "mujoco")
SEED0 = 5000


def _row(r: dict) -> dict:
    return {"finish_rate": r["success_rate"], "median_lap_s": r["lap_time_s"]["median"],
            "crash_reasons": r.get("crash_reasons"), "policy": r["policy"]}  # fmt: skip


def random_layouts(episodes: int, policy: str) -> dict:
    pol = resolve_policy("default" if policy == "auto" else policy)
    out = {}
    for b in BACKENDS:
        t0 = time.perf_counter()
        r = evaluate_policy(pol, None, episodes=episodes, num_gates=10, backend=b,
                            randomize=True, seed=SEED0, difficulty=1.0)  # fmt: skip
        out[b] = {**_row(r), "wall_s": round(time.perf_counter() - t0, 1)}
        print("random", b, out[b], flush=True)
    return out


def builtin(seeds: int, policy: str) -> dict:
    out = {}
    for name in BUILTIN_TRACKS:
        pol = resolve_policy(policy, track=resolve_track(name))
        out[name] = {}
        for b in BACKENDS:
            r = evaluate_policy(pol, name, episodes=seeds, backend=b, randomize=True, seed=SEED0)
            out[name][b] = _row(r)
        print(name, {b: (v["finish_rate"], v["median_lap_s"]) for b, v in out[name].items()},
              flush=True)  # fmt: skip
    return out


def gaps(res: dict) -> dict:
    """Finish-rate difference from PyBullet, points, for the random layouts and each track."""
    rows = {"random": res["random"], **res["builtin"]}
    return {
        k: {b: round(100 * (v[b]["finish_rate"] - v["pybullet"]["finish_rate"]), 1)
            for b in BACKENDS if b != "pybullet"}
        for k, v in rows.items()
    }  # fmt: skip


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--episodes", type=int, default=300)
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--policy", default="auto", help="auto, a shipped name or an exported path")
    ap.add_argument("--json", default=None)
    args = ap.parse_args()
    t0 = time.perf_counter()
    res = {"policy": args.policy, "random": random_layouts(args.episodes, args.policy),
           "builtin": builtin(args.seeds, args.policy)}  # fmt: skip
    res["gap_points_vs_pybullet"] = gaps(res)
    res["wall_s"] = round(time.perf_counter() - t0, 1)
    print(json.dumps(res, indent=1))
    if args.json:
        atomic_write_json(args.json, res)


if __name__ == "__main__":
    main()
