"""Fly one race in a single-drone env and build its report.

For now the pilot is the scripted controller flying on ground-truth observations; the vision
pipeline (camera -> detector -> estimator -> policy) plugs into the same loop.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from icarus_vision.policy.scripted import ScriptedController
from icarus_vision.racing.report import empty_perception, validate_report
from icarus_vision.sim.builtin import resolve_track
from icarus_vision.sim.config import EnvConfig, RandomizationConfig
from icarus_vision.sim.quad import QuadParams
from icarus_vision.sim.registration import make_env
from icarus_vision.sim.track import Track


@dataclass
class RaceResult:
    """A flown race: the report plus the trajectory for plots.

    Attributes:
        report: the ARCHITECTURE.md race report.
        t: (T,) time, s; pos: (T, 3) world positions; speed: (T,) m/s.
        track: the track as flown.
    """

    report: dict
    t: np.ndarray
    pos: np.ndarray
    speed: np.ndarray
    track: Track


def run_race(
    track: str | Track | None = None,
    *,
    quad: QuadParams | None = None,
    laps: int | None = None,
    seed: int = 0,
    backend: str = "pybullet",
    randomize: bool = False,
) -> RaceResult:
    """Fly ``track`` once with the scripted controller on ground-truth observations."""
    base = resolve_track(track)
    if laps is not None:
        base = base.with_laps(laps)
    quad = quad or QuadParams()
    cfg = EnvConfig(track=base, quad=quad, randomization=RandomizationConfig(enabled=randomize))
    env = make_env(backend, config=cfg)
    controller = ScriptedController(quad)
    wall0 = time.perf_counter()
    obs, _ = env.reset(seed=seed)
    ts, positions, speeds = [0.0], [obs[:3].copy()], [0.0]
    while True:
        obs, _, term, trunc, info = env.step(controller.act_env(env, obs[None])[0])
        ts.append(info["time"])
        positions.append(obs[:3].copy())
        speeds.append(float(np.linalg.norm(obs[3:6])))
        if term or trunc:
            break
    wall = time.perf_counter() - wall0
    flown = env.unwrapped.track
    if hasattr(env, "close"):
        env.close()
    speeds_a = np.array(speeds)
    finished = bool(info["all_gates_passed"] and not info["crashed"])
    report = {
        "track": base.name, "laps": base.laps, "seed": seed, "quad": quad.name,
        "detector": None, "policy": "scripted", "backend": backend,
        "finished": finished, "crashed": bool(info["crashed"]), "crash_reason": info["crash_reason"],
        "gates_total": info["gates_total"], "gates_passed": info["gates_passed"],
        "lap_times_s": [round(x, 4) for x in info["lap_times"]],
        "total_time_s": round(info["time"], 4) if finished else None,
        "max_speed_mps": round(float(speeds_a.max()), 3),
        "mean_speed_mps": round(float(speeds_a.mean()), 3),
        "sim_time_s": round(info["time"], 4), "wall_time_s": round(wall, 4),
        "realtime_factor": round(info["time"] / wall, 3) if wall > 0 else None,
        "perception": empty_perception(),
        "time_optimal_s": None, "time_optimal_ratio": None,
    }  # fmt: skip
    validate_report(report)
    return RaceResult(report, np.array(ts), np.array(positions), speeds_a, flown)
