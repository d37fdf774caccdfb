"""Policy learning-speed figures: single gate within one minute, and a curve plot of a run.

    .venv/bin/python benchmarks/policy_targets.py single-gate [--minutes 1] [--episodes 200]
    .venv/bin/python benchmarks/policy_targets.py ten-gates [--minutes 20] [--episodes 300]
    .venv/bin/python benchmarks/policy_targets.py pybullet [--policy default] [--episodes 100] [--seeds 7 11 13]
    .venv/bin/python benchmarks/policy_targets.py lap-times [--policy default]
    .venv/bin/python benchmarks/policy_targets.py curves RUN_DIR [RUN_DIR ...] --png docs/policy_training_curves.png

``single-gate`` trains the fast preset on the single-gate stage for a wall-clock budget, then flies
the deterministic policy on that many random single-gate tracks (randomisation and perception noise
as in training) and prints the success rate. ``ten-gates`` trains through the whole curriculum for
a wall-clock budget and flies the run's best and last models on random 10-gate tracks.
``pybullet`` flies a policy on the PyBullet backend with ground-truth observations on random
10-gate tracks with randomisation on, ``--episodes`` tracks per seed, and pools the seeds.
``lap-times`` flies the policy and the scripted controller, randomisation on, on 300 random
10-gate tracks (seed 5) and 20 episodes each of ``grand-prix`` and ``ten-gates``: success rate and
median lap time of each. ``curves`` plots success rate and return against
wall-clock from runs' ``metrics.json`` (or ``checkpoints/last_state.json``).
"""

from __future__ import annotations

import argparse
import json
import tempfile
from dataclasses import replace
from pathlib import Path

from icarus_vision.policy.config import FAST, CurriculumConfig
from icarus_vision.policy.evaluate import evaluate_policy
from icarus_vision.policy.export import load_policy
from icarus_vision.policy.pilots import resolve_policy
from icarus_vision.policy.plots import plot_training_curves
from icarus_vision.policy.train import train_policy


def single_gate(minutes: float, episodes: int) -> dict:
    cfg = replace(
        FAST, curriculum=CurriculumConfig(stages=(1,)), checkpoint_every=10**12, eval_every=10**12
    )
    with tempfile.TemporaryDirectory() as tmp:
        res = train_policy(
            cfg, f"{tmp}/run", seed=0, timesteps=10**9, max_wall_s=60.0 * minutes, verbose=0
        )
        pol = load_policy(res.policy_path)
        ev = evaluate_policy(pol, None, episodes=episodes, num_gates=1, randomize=True, seed=123)
    return {"minutes": minutes, "timesteps": res.timesteps, "success_rate": ev["success_rate"],
            "crash_reasons": ev["crash_reasons"]}  # fmt: skip


def ten_gates(minutes: float, episodes: int, out: Path) -> dict:
    """The fast preset with the extended observation through the whole curriculum for a wall-clock
    budget; the run's best and last models flown on random 10-gate tracks with randomisation."""
    cfg = replace(FAST, observation="extended", checkpoint_every=2_000_000, eval_every=2_000_000)
    res = train_policy(cfg, out, seed=0, timesteps=10**9, max_wall_s=60.0 * minutes, verbose=0)
    row = {"minutes": minutes, "timesteps": res.timesteps}
    for name in ("best", "policy"):
        pol = load_policy(out / f"{name}.safetensors")
        row[name] = evaluate_policy(
            pol, None, episodes=episodes, num_gates=10, randomize=True, seed=5
        )["success_rate"]
    return row


def pybullet(policy: str, episodes: int, seeds: list[int]) -> dict:
    pol = resolve_policy(policy)
    rows = [
        evaluate_policy(
            pol, None, episodes=episodes, num_gates=10, backend="pybullet", randomize=True, seed=s
        )
        for s in seeds
    ]
    n_ok = sum(round(r["success_rate"] * r["episodes"]) for r in rows)
    n = sum(r["episodes"] for r in rows)
    reasons: dict[str, int] = {}
    for r in rows:
        for k, v in r["crash_reasons"].items():
            reasons[k] = reasons.get(k, 0) + v
    return {"policy": policy, "seeds": {s: r["success_rate"] for s, r in zip(seeds, rows, strict=True)},
            "episodes": n, "success_rate": round(n_ok / n, 4), "crash_reasons": reasons}  # fmt: skip


def lap_times(policy: str) -> list[dict]:
    rows = []
    for track, episodes, seed in ((None, 300, 5), ("grand-prix", 20, 0), ("ten-gates", 20, 0)):
        row = {"track": track or "random-10", "episodes": episodes}
        for name in (policy, "scripted"):
            ev = evaluate_policy(
                resolve_policy(name), track, episodes=episodes, randomize=True, seed=seed
            )
            row[name] = {
                "success_rate": ev["success_rate"],
                "lap_median_s": ev["lap_time_s"]["median"],
            }
        rows.append(row)
    return rows


def _metrics(run: Path) -> list[dict]:
    if (run / "metrics.json").is_file():
        return json.loads((run / "metrics.json").read_text())
    return json.loads((run / "checkpoints" / "last_state.json").read_text())["metrics"]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    a = sub.add_parser("single-gate")
    a.add_argument("--minutes", type=float, default=1.0)
    a.add_argument("--episodes", type=int, default=200)
    t = sub.add_parser("ten-gates")
    t.add_argument("--minutes", type=float, default=20.0)
    t.add_argument("--episodes", type=int, default=300)
    t.add_argument("--out", type=Path, default=Path("runs/policy-ten-gates"))
    b = sub.add_parser("pybullet")
    b.add_argument("--policy", default="default")
    b.add_argument("--episodes", type=int, default=100)
    b.add_argument("--seeds", type=int, nargs="+", default=[7, 11, 13])
    lt = sub.add_parser("lap-times")
    lt.add_argument("--policy", default="default")
    c = sub.add_parser("curves")
    c.add_argument("runs", nargs="+", type=Path)
    c.add_argument("--png", type=Path, required=True)
    c.add_argument("--title", default="PPO, fast preset, random tracks, curriculum 1-3-5-10 gates")
    args = ap.parse_args()
    if args.cmd == "single-gate":
        print(json.dumps(single_gate(args.minutes, args.episodes), indent=2))
    elif args.cmd == "ten-gates":
        print(json.dumps(ten_gates(args.minutes, args.episodes, args.out), indent=2))
    elif args.cmd == "pybullet":
        print(json.dumps(pybullet(args.policy, args.episodes, args.seeds), indent=2))
    elif args.cmd == "lap-times":
        print(json.dumps(lap_times(args.policy), indent=2))
    else:
        plot_training_curves({r.name: _metrics(r) for r in args.runs}, args.png, args.title)
        print(f"wrote {args.png}")


if __name__ == "__main__":
    main()
