"""Fly one race with the whole pipeline in the loop and build its report.

``run_race`` resolves the track, quadrotor, detector and pilot, builds the physics backend's
world and the rendering scene, flies ``fly_loop`` and returns the report of ARCHITECTURE.md with the
trajectory and, when asked, the video frames.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace

import numpy as np

from icarus_vision.estimator.config import config_for_detector
from icarus_vision.gate_detect.registry import make_detector, parse_spec
from icarus_vision.policy.export import ExportedPolicy
from icarus_vision.policy.lookahead import Lookahead, LookaheadConfig, as_config
from icarus_vision.policy.pilots import resolve_policy
from icarus_vision.policy.scripted import ScriptedController
from icarus_vision.racing.loop import LoopRecord, fly_loop
from icarus_vision.racing.report import validate_report
from icarus_vision.racing.warmup import warm_up
from icarus_vision.render.camera import Camera
from icarus_vision.render.randomize import load_recipe, sample_visuals
from icarus_vision.sim.builtin import resolve_track
from icarus_vision.sim.config import EnvConfig, RandomizationConfig
from icarus_vision.sim.quad import QuadParams
from icarus_vision.sim.registration import check_backend, make_env
from icarus_vision.sim.track import Track

DETECTORS = ("cnn", "opencv", "oracle")
PLAN_CACHE = "runs/plans"
VISION_MARGIN_M = 0.1
"""race --lookahead with a detector: the filter's model counts a flight within this of a gate's
frame as a crash (the race loop's gates are where vision puts them, a few centimetres off)."""


def time_optimal(track: Track, quad: QuadParams, cache_dir: str = PLAN_CACHE) -> float | None:
    """The minimum time of (track, quad) from the `plan` cache, or None when none was planned."""
    from icarus_vision.planning.command import plan_time_for_race

    return plan_time_for_race(track, quad, cache_dir)


def planned_ghost(
    track: Track, quad: QuadParams, cache_dir: str = PLAN_CACHE
) -> tuple[np.ndarray, np.ndarray] | None:
    """The cached time-optimal trajectory of (track, quad) as (t (M,) s, pos (M, 3)), or None."""
    from icarus_vision.planning.cache import load_cached

    hit = load_cached(track, quad, cache_dir)
    return None if hit is None else (np.asarray(hit.t), np.asarray(hit.pos))


@dataclass
class RaceResult:
    """A flown race: the report plus the trajectory for plots and the video frames.

    Attributes:
        report: the ARCHITECTURE.md race report.
        t: (T,) time, s; pos: (T, 3) world positions; speed: (T,) m/s.
        track: the track as flown (after randomisation).
        video: list of RGB frames at the camera rate (empty unless asked for).
        ghost: the cached time-optimal plan as (t (M,) s, pos (M, 3)), or None.
        loop: the loop's per-frame record (perception error, true gate distance, target agreement).
    """

    report: dict
    t: np.ndarray
    pos: np.ndarray
    speed: np.ndarray
    track: Track
    video: list
    ghost: tuple[np.ndarray, np.ndarray] | None = None
    loop: LoopRecord | None = None


def _lookahead(
    policy: ExportedPolicy, cfg: EnvConfig, detector: str, config: LookaheadConfig
) -> Lookahead:
    """The look-ahead filter of a race: with the camera in the loop its model keeps
    ``VISION_MARGIN_M`` from the gates, which it knows only as well as vision has measured them."""
    margin = 0.0 if detector == "oracle" else VISION_MARGIN_M
    return Lookahead(policy, cfg, replace(config, margin_m=margin))


def _pilot(policy: ExportedPolicy | str, quad: QuadParams):
    if isinstance(policy, ExportedPolicy):
        return lambda obs, yaw: policy.act(obs)
    ctrl = ScriptedController(quad)
    return lambda obs, yaw: ctrl.act(obs[None, :15], np.array([yaw]))[0]


def run_race(
    track: str | Track | None = None,
    *,
    quad: QuadParams | None = None,
    laps: int | None = None,
    seed: int = 0,
    detector: str = "cnn",
    policy: str | None = "auto",
    backend: str = "pybullet",
    randomize: bool = False,
    latency_frames: int = 1,
    video: bool = False,
    recipe: str | None = "gates-v1",
    open_loop: bool = False,
    lookahead: bool | LookaheadConfig = False,
) -> RaceResult:
    """Fly ``track`` once with camera, detector, estimator and pilot in the loop.

    Args:
        detector: ``cnn[:PATH]``, ``opencv`` or ``oracle`` (true gate position, no camera).
        policy: ``auto`` (the track's shipped specialist, else the generalist), ``default`` (the
            generalist), a shipped name, a path to an exported policy, or ``scripted``.
        backend: physics backend (batched, pybullet, mujoco or a plug-in's name); the camera
            renders through PyBullet either way.
        randomize: mass, thrust, wind and gate jitter from the training ranges, and how the
            world looks from ``recipe``.
        recipe: with ``randomize``, the visual domain-randomisation recipe (a packaged name or
            a path) the camera's world is drawn from, once per race from ``seed``: gate looks,
            ground, sky or hall, distractors, light and sensor effects (the camera itself stays
            the quadrotor file's: the estimator knows it). None: the default look.
        latency_frames: camera frames between an image and its detections reaching the estimator.
        video: keep composed video frames (FPV with detections beside a top view).
        open_loop: the pilot flies on the truth while camera, detector and estimator run and are
            recorded (``RaceResult.loop``): perception measured on the oracle's flight.
        lookahead: fly the policy through the look-ahead safety filter (``policy.lookahead``);
            True: its default settings, or a ``LookaheadConfig`` (its ``margin_m`` is the race's:
            ``VISION_MARGIN_M`` with a detector); the report's ``policy`` then reads
            ``NAME+lookahead``, or ``NAME+lookahead-race`` in the racing mode (``racing()``).
    """
    check_backend(backend)
    if latency_frames < 0:
        raise ValueError(f"latency_frames must be >= 0, got {latency_frames}")
    det_name, _ = parse_spec(detector)
    if det_name not in DETECTORS:
        raise ValueError(f"unknown detector {det_name!r}; choose cnn[:PATH], opencv or oracle")
    detector_obj = None
    if det_name != "oracle":
        detector_obj = make_detector(detector)  # fail before flying if it cannot be built
    base = resolve_track(track)
    if laps is not None:
        base = base.with_laps(laps)
    quad = quad or QuadParams()
    pilot_spec = resolve_policy(policy, track=base)
    if isinstance(pilot_spec, ExportedPolicy):
        pilot_spec.check_quad(quad)
        pilot_spec.check_track(base)
    la = as_config(lookahead)
    if la is not None and not isinstance(pilot_spec, ExportedPolicy):
        raise ValueError("--lookahead filters an exported policy, not the scripted controller")
    ghost = planned_ghost(base, quad)
    obs_mode = pilot_spec.observation if isinstance(pilot_spec, ExportedPolicy) else "basic"
    cfg = EnvConfig(
        track=base,
        quad=quad,
        randomization=RandomizationConfig(enabled=randomize),
        observation=obs_mode,
    )
    looks = load_recipe(recipe) if randomize and recipe is not None else None  # fail before flying
    env = make_env(backend, config=cfg)
    camera = Camera.from_params(quad.camera)
    scene = look = None
    frames: list = []
    wall0 = time.perf_counter()
    try:
        env.reset(seed=seed)
        flown = env.unwrapped.track
        needs_camera = det_name != "oracle" or video
        if needs_camera:
            from icarus_vision.render.scene import Scene

            if looks is None:
                scene = Scene(flown, camera)
            else:  # the world's look, drawn once per race (a stream of its own)
                look = sample_visuals(looks, np.random.default_rng([seed, 36]), flown, camera)
                scene = Scene(flown, camera, look.style, look.distractors)
        if detector_obj is not None:
            warm_up(detector_obj, scene, flown)  # compile before the clock starts
        wall0 = time.perf_counter()
        on_frame = None
        if video:
            from icarus_vision.racing.video import VideoComposer

            composer = VideoComposer(flown, camera, scene, ghost, 1.0 / quad.camera.rate_hz)

            def on_frame(rgb, dets, est, state):
                frames.append(composer.compose(rgb, dets, est, state))

        rec = fly_loop(env, _pilot(pilot_spec, quad), cfg.obs_dim, detector=detector_obj or detector, camera=camera,
                       scene=scene, seed=seed, prior=base, latency_frames=latency_frames, on_frame=on_frame,
                       estimator=config_for_detector(det_name), look=look, open_loop=open_loop,
                       lookahead=None if la is None else _lookahead(pilot_spec, cfg, det_name, la))  # fmt: skip
    finally:
        env.close()
        if scene is not None:
            scene.close()
    wall = time.perf_counter() - wall0
    info = rec.info
    speeds = np.array([0.0, *rec.speed])
    finished = bool(info["all_gates_passed"] and not info["crashed"])
    err = np.array(rec.rel_err)
    seen = det_name != "oracle" and rec.frames > 0  # the oracle has no perception to report
    perception = {
        "frames": rec.frames,
        "detection_rate": round(rec.detected / rec.frames, 4) if seen else None,
        "rel_gate_error_m": {
            "median": round(float(np.median(err)), 4) if seen and err.size else None,
            "p95": round(float(np.percentile(err, 95)), 4) if seen and err.size else None,
        },
    }
    policy_name = pilot_spec.name if isinstance(pilot_spec, ExportedPolicy) else "scripted"
    if la is not None:
        policy_name += "+lookahead-race" if la.race_amplitudes else "+lookahead"
    report = {
        "track": base.name, "laps": base.laps, "seed": seed, "quad": quad.name,
        "detector": det_name, "policy": policy_name, "backend": backend,
        "finished": finished, "crashed": bool(info["crashed"]), "crash_reason": info["crash_reason"],
        "gates_total": info["gates_total"], "gates_passed": info["gates_passed"],
        "lap_times_s": [round(x, 4) for x in info["lap_times"]],
        "total_time_s": round(info["finish_time"], 4) if finished else None,
        "max_speed_mps": round(float(speeds.max()), 3),
        "mean_speed_mps": round(float(speeds.mean()), 3),
        "sim_time_s": round(info["time"], 4), "wall_time_s": round(wall, 4),
        "realtime_factor": round(info["time"] / wall, 3) if wall > 0 else None,
        "perception": perception,
        "time_optimal_s": None, "time_optimal_ratio": None,
    }  # fmt: skip
    optimal = time_optimal(base, quad)
    if optimal is not None:
        report["time_optimal_s"] = round(optimal, 4)
        if finished:
            report["time_optimal_ratio"] = round(info["finish_time"] / optimal, 4)
    validate_report(report)
    pos = np.array([np.asarray(flown.start_pos), *rec.pos])
    t = np.array([0.0, *rec.t])
    return RaceResult(report, t, pos, speeds, flown, frames, ghost, rec)
