"""The racing policy's figures in the whole loop (PyBullet, camera, detector, estimator, policy).

    .venv/bin/python benchmarks/race_policy.py builtin [--seeds 20] [--detector cnn]
        [--policy default] [--backend pybullet] [--json PATH]
    .venv/bin/python benchmarks/race_policy.py specialists [--seeds 20] [--track NAME]
        [--policy auto] [--json PATH]
    .venv/bin/python benchmarks/race_policy.py vision [--tracks 140] [--difficulty 1.0]
        [--policy default] [--json PATH]
    (each with ``--lookahead``: through the look-ahead safety filter, as ``race --lookahead``;
    ``--lookahead-race``: its racing mode, as ``race --lookahead-race``)

``builtin``: every built-in track, `race --randomize --detector cnn --policy default` (the
generalist; ``--policy auto`` flies the shipped specialists where there are some) on
``--backend`` (default pybullet) for seeds 100.., finish rate per track, median detection rate, and the median lap over
the track's time-optimal plan where one is cached (`icarus-vision plan --track NAME`).
``specialists``: `grand-prix` and `split-s` with `--policy auto` (their shipped specialists; a
candidate with ``--track split-s --policy runs/x/policy``), seeds 100.., randomised, with ground truth (`--detector oracle`) and with the CNN: finish rate and median
lap / time-optimal (plans must be cached).
``vision``: random race layouts (``race_track(10, 3000 + i, difficulty)``), randomised, flown by
the generalist with the CNN and with the oracle: the finish rates side by side.
"""

from __future__ import annotations

import argparse
import json
import statistics
import time

from icarus_vision.fileio import atomic_write_json
from icarus_vision.policy.lookahead import LookaheadConfig, racing
from icarus_vision.racing.runner import RaceResult, run_race
from icarus_vision.sim.builtin import BUILTIN_TRACKS
from icarus_vision.sim.race_layouts import race_track

SEED0 = 100


def _summary(reports: list[dict]) -> dict:
    done = [r for r in reports if r["finished"]]
    ratios = [r["time_optimal_ratio"] for r in done if r["time_optimal_ratio"] is not None]
    det = [
        r["perception"]["detection_rate"]
        for r in reports
        if r["perception"]["detection_rate"] is not None
    ]
    return {
        "races": len(reports),
        "finish_rate": round(len(done) / len(reports), 4),
        "median_lap_s": round(statistics.median(r["total_time_s"] for r in done), 4)
        if done
        else None,
        "median_ratio": round(statistics.median(ratios), 4) if ratios else None,
        "detection_rate_median": round(statistics.median(det), 4) if det else None,
        "failures": [
            (r["seed"], r["crash_reason"], r["gates_passed"]) for r in reports if not r["finished"]
        ],
        "policy": sorted({r["policy"] for r in reports}),
    }


def builtin(
    seeds: int, detector: str, policy: str = "default", backend: str = "pybullet",
    recipe: str | None = "gates-v1", lookahead: bool | LookaheadConfig = False,
) -> dict:  # fmt: skip
    out = {}
    for name in BUILTIN_TRACKS:
        reports = [run_race(name, detector=detector, policy=policy, seed=s, randomize=True, recipe=recipe,
                            backend=backend, lookahead=lookahead).report
                   for s in range(SEED0, SEED0 + seeds)]  # fmt: skip
        out[name] = _summary(reports)
        print(name, out[name], flush=True)
    out["all_finish_rate"] = round(statistics.mean(v["finish_rate"] for v in out.values()), 4)
    return out


def specialists(
    seeds: int,
    recipe: str | None = "gates-v1",
    policy: str = "auto",
    tracks: tuple[str, ...] = ("grand-prix", "split-s"),
    lookahead: bool | LookaheadConfig = False,
) -> dict:
    out = {}
    for name in tracks:
        for det in ("oracle", "cnn"):
            reports = [run_race(name, detector=det, policy=policy, seed=s, randomize=True, recipe=recipe,
                                lookahead=lookahead).report
                       for s in range(SEED0, SEED0 + seeds)]  # fmt: skip
            out[f"{name}/{det}"] = _summary(reports)
            print(name, det, out[f"{name}/{det}"], flush=True)
    return out


def vision_race(
    i: int, detector: str, policy: str, difficulty: float = 1.0,
    recipe: str | None = "gates-v1", open_loop: bool = False, lookahead: bool | LookaheadConfig = False,
) -> RaceResult:  # fmt: skip
    """The race loop's ``i``-th race: layout ``race_track(10, 3000 + i)``, seed 100 + i,
    randomised (also flown open loop by ``estimator_races.py``)."""
    return run_race(race_track(10, 3000 + i, difficulty=difficulty), detector=detector, policy=policy,
                    seed=SEED0 + i, randomize=True, recipe=recipe, open_loop=open_loop,
                    lookahead=lookahead)  # fmt: skip


def vision(
    tracks: int,
    difficulty: float,
    policy: str = "default",
    recipe: str | None = "gates-v1",
    lookahead: bool | LookaheadConfig = False,
) -> dict:
    out = {}
    for det in ("oracle", "cnn"):
        reports = [vision_race(i, det, policy, difficulty, recipe, lookahead=lookahead).report
                   for i in range(tracks)]  # fmt: skip
        out[det] = _summary(reports)
        print(det, out[det], flush=True)
    out["gap_points"] = round(100 * (out["oracle"]["finish_rate"] - out["cnn"]["finish_rate"]), 1)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("what", choices=["builtin", "specialists", "vision"])
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--tracks", type=int, default=140)
    ap.add_argument("--difficulty", type=float, default=1.0)
    ap.add_argument("--detector", default="cnn")
    ap.add_argument("--policy", default=None,
                    help="builtin: default (the default) or auto; specialists: auto (the default) "
                         "or an exported policy; vision: default (the default) or an exported policy")  # fmt: skip
    ap.add_argument("--track", action="append", default=None,
                    help="specialists: the track(s) to fly (default grand-prix and split-s)")  # fmt: skip
    ap.add_argument("--backend", default="pybullet", help="builtin: the physics backend")
    ap.add_argument("--recipe", default="gates-v1",
                    help="the look race --randomize draws (gates-v1, gates-v3, a path, or none)")  # fmt: skip
    ap.add_argument("--lookahead", action="store_true",
                    help="fly through the look-ahead safety filter (race --lookahead)")  # fmt: skip
    ap.add_argument("--lookahead-race", action="store_true",
                    help="the filter's racing mode (race --lookahead-race)")  # fmt: skip
    ap.add_argument("--json", default=None)
    args = ap.parse_args()
    policy = args.policy or ("auto" if args.what == "specialists" else "default")
    recipe = None if args.recipe == "none" else args.recipe
    filt = racing() if args.lookahead_race else args.lookahead
    t0 = time.perf_counter()
    if args.what == "builtin":
        out = builtin(args.seeds, args.detector, policy, args.backend, recipe, filt)
        out["backend"], out["policy_asked"] = args.backend, policy
    elif args.what == "specialists":
        tracks = tuple(args.track or ("grand-prix", "split-s"))
        out = specialists(args.seeds, recipe, policy, tracks, filt)
        out["policy_asked"] = policy
    else:
        out = vision(args.tracks, args.difficulty, policy, recipe, filt)
    out["lookahead"], out["lookahead_race"] = bool(filt), args.lookahead_race
    out["wall_s"], out["recipe"] = round(time.perf_counter() - t0, 1), recipe
    print(json.dumps(out, indent=1))
    if args.json:
        atomic_write_json(args.json, out)


if __name__ == "__main__":
    main()
