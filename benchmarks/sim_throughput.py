"""Simulation throughput: batched env-steps/s (256 drones), PyBullet and MuJoCo control steps/s (1 drone).

Run on a quiet machine: ``.venv/bin/python benchmarks/sim_throughput.py [--repeats 5]``.
Both figures are measured on one core (the process is pinned to one CPU and BLAS threads are set
to 1). The drones fly the training set-up (random 10-gate tracks, domain randomisation on) under
the scripted controller plus action noise, so episodes look like real flights: drones pass gates,
some crash, finished drones auto-reset onto new random tracks. Only ``env.step`` is timed (the
controller is not); resets are included. The median over repeats is printed.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import time

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("MKL_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from icarus_vision.policy.scripted import ScriptedController  # noqa: E402
from icarus_vision.sim.config import EnvConfig, RandomizationConfig  # noqa: E402
from icarus_vision.sim.registration import make_env  # noqa: E402
from icarus_vision.sim.vec_env import BatchedRacingVecEnv  # noqa: E402


def noisy(ctrl: ScriptedController, env, obs: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    a = ctrl.act_env(env, obs)
    return np.clip(a + rng.normal(0.0, 0.1, a.shape), -1, 1)


def bench_batched(n: int = 256, steps: int = 500) -> tuple[float, float]:
    """Returns (env-steps/s, episodes finished per 1000 env-steps)."""
    cfg = EnvConfig(
        random_tracks=True, num_gates=10, randomization=RandomizationConfig(enabled=True)
    )
    vec = BatchedRacingVecEnv(n, cfg)
    vec.seed(0)
    obs = vec.reset()
    ctrl, rng = ScriptedController(cfg.quad), np.random.default_rng(0)
    for _ in range(100):  # warm-up: spread the drones along their tracks
        obs, *_ = vec.step(noisy(ctrl, vec, obs, rng))
    spent, episodes = 0.0, 0
    for _ in range(steps):
        a = noisy(ctrl, vec, obs, rng)
        t0 = time.perf_counter()
        obs, _, done, _ = vec.step(a)
        spent += time.perf_counter() - t0
        episodes += int(done.sum())
    return n * steps / spent, 1000 * episodes / (n * steps)


def bench_single(backend: str, steps: int = 2000) -> float:
    """Control steps/s of one drone on ``backend`` flying ``ten-gates`` (resets included)."""
    env = make_env(backend, track="ten-gates")
    obs, _ = env.reset(seed=0)
    ctrl, rng = ScriptedController(env.config.quad), np.random.default_rng(0)
    spent = 0.0
    for _ in range(steps):
        a = noisy(ctrl, env, obs[None], rng)[0]
        t0 = time.perf_counter()
        obs, _, term, trunc, _ = env.step(a)
        if term or trunc:
            obs, _ = env.reset()
        spent += time.perf_counter() - t0
    env.close()
    return steps / spent


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--drones", type=int, default=256)
    ap.add_argument("--json", default=None, help="also write the figures to this JSON file")
    args = ap.parse_args()
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {sorted(os.sched_getaffinity(0))[0]})
    runs = [bench_batched(args.drones) for _ in range(args.repeats)]
    batched = [r[0] for r in runs]
    pyb = [bench_single("pybullet") for _ in range(args.repeats)]
    mjc = [bench_single("mujoco") for _ in range(args.repeats)]
    result = {
        "machine": f"{platform.processor() or platform.machine()}, {os.cpu_count()} cores, 1 core used",
        "batched_env_steps_per_s": round(statistics.median(batched)),
        "batched_drones": args.drones,
        "batched_episodes_per_1000_steps": round(statistics.median(r[1] for r in runs), 2),
        "pybullet_control_steps_per_s": round(statistics.median(pyb)),
        "mujoco_control_steps_per_s": round(statistics.median(mjc)),
        "repeats": args.repeats,
        "batched_all": [round(x) for x in batched],
        "pybullet_all": [round(x) for x in pyb],
        "mujoco_all": [round(x) for x in mjc],
    }
    print(json.dumps(result, indent=2))
    if args.json:
        from icarus_vision.fileio import atomic_write_json

        atomic_write_json(args.json, result)


if __name__ == "__main__":
    main()
