"""End-to-end PPO throughput of a preset (environment steps per wall-clock second, training included).

    .venv/bin/python benchmarks/ppo_throughput.py [--preset fast] [--timesteps 1000000] [--repeats 3]

Runs ``train_policy`` on the single-gate curriculum stage (no evaluation or checkpoints inside the
timed window) and reports the median steps/s over repeats. Run it on a quiet machine: the fast
preset uses one core for the simulator and one torch thread.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import tempfile
import time
from dataclasses import replace

from icarus_vision.policy.config import PRESETS, CurriculumConfig
from icarus_vision.policy.train import train_policy


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--preset", default="fast", choices=sorted(PRESETS))
    ap.add_argument("--timesteps", type=int, default=1_000_000)
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()
    cfg = replace(PRESETS[args.preset], curriculum=CurriculumConfig(stages=(10,)),
                  checkpoint_every=10**12, eval_every=10**12)  # fmt: skip
    rates = []
    for k in range(args.repeats):
        with tempfile.TemporaryDirectory() as tmp:
            t0 = time.perf_counter()
            res = train_policy(cfg, f"{tmp}/run", seed=k, timesteps=args.timesteps, verbose=0)
            rates.append(res.timesteps / (time.perf_counter() - t0))
    print(json.dumps({
        "preset": args.preset,
        "env_steps_per_s": round(statistics.median(rates)),
        "all": [round(r) for r in rates],
        "timesteps": args.timesteps,
        "machine": f"{platform.machine()}, {os.cpu_count()} cores",
    }, indent=2))  # fmt: skip


if __name__ == "__main__":
    main()
