"""Basic (15-D) vs extended (21-D) observation: same training budget, same seeds, same tracks.

    .venv/bin/python benchmarks/policy_observation.py [--timesteps 3000000] [--gates 3] [--out runs/obs-compare]

Trains the fast preset twice on random tracks of ``--gates`` gates (curriculum fixed at that count,
randomisation and perception noise on), differing only in ``observation``; then flies both
deterministic policies on random 10-gate tracks and on the built-in tracks whose gates do not face
along the line from the previous gate (``hairpin``: a gate flown straight back; ``split-s``: a
gate under another, flown the other way). Prints a JSON table.
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import replace
from pathlib import Path

from icarus_vision.fileio import atomic_write_json
from icarus_vision.policy.config import FAST, CurriculumConfig
from icarus_vision.policy.evaluate import evaluate_policy
from icarus_vision.policy.export import load_policy
from icarus_vision.policy.train import train_policy

TRACKS = ("hairpin", "split-s", "ten-gates", "grand-prix")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--timesteps", type=int, default=3_000_000)
    ap.add_argument("--gates", type=int, default=3)
    ap.add_argument("--episodes", type=int, default=200)
    ap.add_argument("--out", default="runs/obs-compare")
    args = ap.parse_args()
    results = {}
    for obs in ("basic", "extended"):
        cfg = replace(FAST, observation=obs, curriculum=CurriculumConfig(stages=(args.gates,)),
                      checkpoint_every=10**12, eval_every=10**12)  # fmt: skip
        t0 = time.perf_counter()
        res = train_policy(cfg, Path(args.out) / obs, seed=0, timesteps=args.timesteps, verbose=0)
        wall = time.perf_counter() - t0
        pol = load_policy(res.policy_path)
        row = {"train_wall_s": round(wall, 1), "timesteps": res.timesteps}
        for n in (args.gates, 10):
            r = evaluate_policy(
                pol, None, episodes=args.episodes, num_gates=n, randomize=True, seed=1
            )
            row[f"random-{n}"] = r["success_rate"]
        for t in TRACKS:
            r = evaluate_policy(pol, t, episodes=20, randomize=True, seed=1)
            row[t] = r["success_rate"]
        results[obs] = row
        print(obs, json.dumps(row), flush=True)
    atomic_write_json(Path(args.out) / "comparison.json", results)
    print(json.dumps(results, indent=2))


if __name__ == "__main__":
    main()
