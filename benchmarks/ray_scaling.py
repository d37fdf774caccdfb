"""What Ray costs and gives on this machine: ``gen-dataset --ray`` and ``sweep`` against the local way.

    .venv/bin/python benchmarks/ray_scaling.py dataset [--num-images 600] [--runs 3] [--json PATH]
    .venv/bin/python benchmarks/ray_scaling.py sweep [--minutes 3] [--json PATH]

``dataset``: the gates-v1 dataset rendered by 2 local worker processes and by Ray tasks on the 2
local cores, runs interleaved; images per second of rendering (Ray's start-up excluded, as the
workers' is included), medians; and whether the two folders hold identical bytes.
``sweep``: two trials of the fast preset (learning rates 1e-3 and 5e-4), ``--minutes`` each, run
by ``sweep`` (two at a time, one core each) and then one after another by ``train_policy`` (the
CLI's way, two torch threads): total environment steps per second of wall-clock, the ratio, and
the time from the sweep's start until its first trial trained.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import statistics
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RECIPE = ROOT / "datasets" / "gates-v1.toml"


def _digest(folder: Path) -> str:
    h = hashlib.sha256()
    for p in sorted(folder.rglob("*")):
        if p.is_file():
            h.update(str(p.relative_to(folder)).encode())
            h.update(p.read_bytes())
    return h.hexdigest()


def dataset(num_images: int, runs: int) -> dict:
    from icarus_vision.dataset import generate_dataset
    from icarus_vision.ray_runtime import start_ray

    start_ray(None)
    rates = {"workers": [], "ray": []}
    digests = {}
    for _ in range(runs):
        for way in ("workers", "ray"):
            with tempfile.TemporaryDirectory(prefix="icarus-ray-") as tmp:
                r = generate_dataset(RECIPE, Path(tmp) / "ds", num_images, workers=2, seed=0,
                                     ray=way == "ray")  # fmt: skip
                rates[way].append(r.images_per_s)
                digests[way] = _digest(Path(tmp) / "ds")
            print(way, round(r.images_per_s, 1), flush=True)
    med = {k: round(statistics.median(v), 1) for k, v in rates.items()}
    return {"num_images": num_images, "runs": runs, "images_per_s": med,
            "ratio_ray_over_workers": round(med["ray"] / med["workers"], 3),
            "identical_bytes": digests["ray"] == digests["workers"],
            "all": {k: [round(x, 1) for x in v] for k, v in rates.items()}}  # fmt: skip


SPACE = """
[base]
preset = "fast"
observation = "extended"
[search]
"ppo.learning_rate" = { loguniform = [1e-4, 3e-3] }
[objective]
gates = 10
episodes = 64
[[start]]
"ppo.learning_rate" = 1e-3
[[start]]
"ppo.learning_rate" = 5e-4
"""


def sweep(minutes: float) -> dict:
    from icarus_vision.policy.sweep import load_space, run_sweep
    from icarus_vision.policy.sweep.trial import STARTED
    from icarus_vision.policy.train import train_policy

    with tempfile.TemporaryDirectory(prefix="icarus-sweep-") as tmp:
        tmp = Path(tmp)
        (tmp / "space.toml").write_text(SPACE)
        t0 = time.time()
        state = run_sweep(tmp / "space.toml", tmp / "sweep", trials=2, trial_minutes=minutes,
                          reports=2, seed=0)  # fmt: skip
        sweep_wall = time.time() - t0
        firsts = [json.loads((tmp / "sweep" / "trials" / k / STARTED).read_text())["time"]
                  for k in state.trials]  # fmt: skip
        sweep_steps = sum(t["timesteps"] for t in state.trials.values())
        space = load_space(tmp / "space.toml")
        seq_steps, t1 = 0, time.time()
        for i, lr in enumerate((1e-3, 5e-4)):
            cfg = space.trial_config({"ppo.learning_rate": lr})
            r = train_policy(cfg, tmp / f"seq{i}", seed=0, max_wall_s=minutes * 60, verbose=0,
                             timesteps=10**12)  # fmt: skip
            seq_steps += r.timesteps
        seq_wall = time.time() - t1
    return {
        "minutes_per_trial": minutes,
        "sweep": {"steps": sweep_steps, "wall_s": round(sweep_wall, 1),
                  "steps_per_s": round(sweep_steps / sweep_wall)},
        "sequential": {"steps": seq_steps, "wall_s": round(seq_wall, 1),
                       "steps_per_s": round(seq_steps / seq_wall)},
        "ratio": round((sweep_steps / sweep_wall) / (seq_steps / seq_wall), 3),
        "first_trial_training_after_s": round(min(firsts) - t0, 1),
        "statuses": sorted(t["status"] for t in state.trials.values()),
    }  # fmt: skip


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("what", choices=["dataset", "sweep"])
    ap.add_argument("--num-images", type=int, default=600)
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--minutes", type=float, default=3.0)
    ap.add_argument("--json", default=None)
    args = ap.parse_args()
    out = dataset(args.num_images, args.runs) if args.what == "dataset" else sweep(args.minutes)
    out["cpus"] = os.cpu_count()
    print(json.dumps(out, indent=1))
    if args.json:
        from icarus_vision.fileio import atomic_write_json

        atomic_write_json(args.json, out)


if __name__ == "__main__":
    main()
