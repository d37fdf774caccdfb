"""Evaluate a pilot (an exported policy or the scripted controller) over many episodes."""

from __future__ import annotations

import numpy as np

from icarus_vision.policy.callbacks import episode_success
from icarus_vision.policy.export import ExportedPolicy
from icarus_vision.policy.lookahead import Lookahead, LookaheadConfig, as_config
from icarus_vision.policy.scripted import ScriptedController
from icarus_vision.sim.builtin import resolve_track
from icarus_vision.sim.config import EnvConfig, RandomizationConfig
from icarus_vision.sim.quad import QuadParams
from icarus_vision.sim.registration import check_backend, make_env
from icarus_vision.sim.track import Track
from icarus_vision.sim.vec_env import BatchedRacingVecEnv


def _pilot(policy: ExportedPolicy | str, env, lookahead: LookaheadConfig | None = None):
    """``f(obs, live) -> actions`` for the drones of ``env`` (live: still racing, or None)."""
    if isinstance(policy, ExportedPolicy) and lookahead is not None:
        filt = Lookahead(policy, env.config, lookahead)
        env = getattr(env, "unwrapped", env)
        return lambda obs, live=None: filt.act(env.core, env.state, obs, live)
    if isinstance(policy, ExportedPolicy):
        return lambda obs, live=None: policy.act(obs)
    if policy == "scripted":
        ctrl = ScriptedController(env.config.quad if hasattr(env, "config") else None)
        return lambda obs, live=None: ctrl.act_env(env, obs)
    raise ValueError(f"unknown policy {policy!r}")


def _summary(episodes: list[dict]) -> dict:
    ok = [e for e in episodes if e["success"]]
    laps = np.array([e["lap_time"] for e in ok]) if ok else np.array([])
    reasons: dict[str, int] = {}
    for e in episodes:
        if e["crash_reason"]:
            reasons[e["crash_reason"]] = reasons.get(e["crash_reason"], 0) + 1
    pct = (lambda q: round(float(np.percentile(laps, q)), 3)) if laps.size else (lambda q: None)
    return {
        "episodes": len(episodes),
        "success_rate": round(len(ok) / len(episodes), 4),
        "crash_rate": round(sum(e["crashed"] for e in episodes) / len(episodes), 4),
        "crash_reasons": reasons,
        "mean_gates_passed": round(float(np.mean([e["gates_passed"] for e in episodes])), 3),
        "lap_time_s": {"median": pct(50), "p10": pct(10), "p90": pct(90)},
        "max_speed_mps": round(float(max(e["max_speed"] for e in episodes)), 3),
        "mean_speed_mps": round(float(np.mean([e["mean_speed"] for e in episodes])), 3),
    }


def evaluate_policy(
    policy: ExportedPolicy | str,
    track: str | None = None,
    *,
    episodes: int = 100,
    num_gates: int = 10,
    backend: str = "batched",
    randomize: bool = False,
    seed: int = 0,
    difficulty: float | None = None,
    quad: QuadParams | None = None,
    lookahead: bool | LookaheadConfig = False,
) -> dict:
    """Fly ``episodes`` episodes and report success, crashes, gates, lap times and speeds.

    Args:
        policy: an ExportedPolicy or "scripted".
        track: a built-in name or TOML path; None flies random tracks of ``num_gates`` gates (one
            new track per episode, seeded).
        backend: "batched" (all episodes at once, one drone each), or any other backend's name
            ("pybullet", "mujoco", a plug-in's), flown one episode after another.
        randomize: domain randomisation (mass, thrust, wind, gate jitter).
        difficulty: random tracks only: None draws classic ``random_track`` layouts, a value in
            [0, 1] ``race_track`` layouts of that difficulty.
        quad: the quadrotor (None: the built-in racer-500g).
        lookahead: fly the policy through the look-ahead safety filter (``policy.lookahead``;
            True: its default settings, or a ``LookaheadConfig``, e.g. ``racing()``). Exported
            policies only.

    Returns:
        The eval-policy JSON fields of ARCHITECTURE.md plus crash reasons and mean speed.
    """
    if episodes < 1:
        raise ValueError(f"episodes must be >= 1, got {episodes}")
    obs_mode = policy.observation if isinstance(policy, ExportedPolicy) else "basic"
    base = None if track is None else resolve_track(track)
    cfg = EnvConfig(
        track=base, quad=quad or QuadParams(), random_tracks=base is None, num_gates=num_gates if base is None else None,
        layout_difficulty=difficulty if base is None else None, randomization=RandomizationConfig(enabled=randomize), observation=obs_mode,
    )  # fmt: skip
    check_backend(backend)
    la = as_config(lookahead)
    if isinstance(policy, ExportedPolicy):
        policy.check_quad(cfg.quad, "this evaluation")
        policy.check_track(base, "this evaluation")
    elif la is not None:
        raise ValueError("--lookahead filters an exported policy, not the scripted controller")
    if backend == "batched":
        results = _run_batched(policy, cfg, episodes, seed, la)
    else:
        results = _run_sequential(policy, cfg, episodes, seed, backend, la)
    name = policy.name if isinstance(policy, ExportedPolicy) else policy
    track_name = base.name if base is not None else f"random-{num_gates}"
    if base is None and difficulty is not None:
        track_name = f"race-{num_gates}-d{difficulty:g}"
    return {"policy": name, "track": track_name, "backend": backend, "randomize": randomize,
            "seed": seed, "lookahead": la is not None,
            "lookahead_race": la is not None and bool(la.race_amplitudes), **_summary(results)}  # fmt: skip


def time_optimal_fields(
    track: Track | None,
    median_lap: float | None,
    *,
    solve: bool = False,
    quad: QuadParams | None = None,
) -> dict:
    """``time_optimal_s`` and ``time_optimal_ratio`` (median lap / plan) for an evaluation.

    Args:
        track: the fixed track flown (None: random tracks, both fields null).
        median_lap: the median lap of the successful episodes, s (None: ratio null).
        solve: plan the track when no plan is cached (the plan is cached for next time).
    """
    from icarus_vision.planning.command import plan_time_for_race, run_plan

    quad = quad or QuadParams()
    out = {"time_optimal_s": None, "time_optimal_ratio": None}
    if track is None:
        return out
    best = plan_time_for_race(track, quad)
    if best is None and solve:
        best = run_plan(track, quad)["time_optimal_s"]
    if best is None:
        return out
    out["time_optimal_s"] = round(float(best), 4)
    if median_lap is not None:
        out["time_optimal_ratio"] = round(float(median_lap) / float(best), 4)
    return out


def _episode(info: dict, speeds: list[float]) -> dict:
    # A finished episode's time is its last passage's (within the step); another's, where it ended.
    end = info["time"] if info["finish_time"] is None else info["finish_time"]
    return {
        "success": episode_success(info), "crashed": bool(info["crashed"]),
        "crash_reason": info["crash_reason"], "gates_passed": info["gates_passed"],
        "lap_time": end, "max_speed": max(speeds), "mean_speed": float(np.mean(speeds)),
    }  # fmt: skip


def _run_batched(policy, cfg: EnvConfig, episodes: int, seed: int, lookahead=None) -> list[dict]:
    env = BatchedRacingVecEnv(episodes, cfg)
    env.seed(seed)
    obs = env.reset()
    act = _pilot(policy, env, lookahead)
    results: list[dict | None] = [None] * episodes
    speed_sum, speed_max, steps = np.zeros(episodes), np.zeros(episodes), np.zeros(episodes)
    live = np.ones(episodes, dtype=bool)
    while live.any():
        obs, _, done, infos = env.step(act(obs, live))
        v = np.linalg.norm(env.state.vel, axis=1)
        speed_sum += v * live
        speed_max = np.where(live, np.maximum(speed_max, v), speed_max)
        steps += live
        for i in np.flatnonzero(done):
            if results[i] is None:
                r = _episode(infos[i], [0.0])
                r["max_speed"], r["mean_speed"] = (
                    float(speed_max[i]),
                    float(speed_sum[i] / steps[i]),
                )
                results[i] = r
        live = np.array([r is None for r in results])
    return results  # type: ignore[return-value]


def _run_sequential(
    policy, cfg: EnvConfig, episodes: int, seed: int, backend: str, lookahead=None
) -> list[dict]:
    env = make_env(backend, config=cfg)
    act = _pilot(policy, env, lookahead)
    results = []
    try:
        for k in range(episodes):
            obs, _ = env.reset(seed=seed + k)
            speeds = []
            while True:
                obs, _, term, trunc, info = env.step(act(obs[None])[0])
                speeds.append(float(np.linalg.norm(obs[3:6])))
                if term or trunc:
                    break
            results.append(_episode(info, speeds))
    finally:
        env.close()
    return results
