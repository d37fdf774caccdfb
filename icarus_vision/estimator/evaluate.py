"""Measure the estimator in closed loop: fly a track in PyBullet, render the camera, detect, estimate.

The pilot is the scripted controller (``policy/scripted.py``, imported lazily: evaluation is the one
place where this stage looks downstream). In closed loop (the default) it flies on the estimate, so
the figures include the effect of the estimate on the flight; otherwise it flies on ground truth and
the estimator only listens.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable

import numpy as np

from icarus_vision.estimator.config import EstimatorConfig, OdometryConfig, config_for_detector
from icarus_vision.estimator.estimate import fill_observation
from icarus_vision.estimator.estimator import GateEstimator
from icarus_vision.estimator.odometry import SimulatedOdometry
from icarus_vision.estimator.prior import displaced_map
from icarus_vision.gate_detect.base import Detector, OracleDetector
from icarus_vision.gate_detect.registry import make_detector, parse_spec
from icarus_vision.render.camera import Camera
from icarus_vision.sim.builtin import resolve_track
from icarus_vision.sim.config import EnvConfig
from icarus_vision.sim.quad import QuadParams
from icarus_vision.sim.registration import make_env
from icarus_vision.sim.track import Track

DISTANCE_BINS = (0.0, 2.0, 5.0, 10.0, float("inf"))
"""Edges of the distance bins of the report, m (camera-to-gate distance, ground truth)."""


def error_summary(err: np.ndarray) -> dict:
    """{"median", "p95", "frames"} of errors (m); None figures when there are none."""
    if len(err) == 0:
        return {"median": None, "p95": None, "frames": 0}
    return {
        "median": round(float(np.median(err)), 4),
        "p95": round(float(np.percentile(err, 95)), 4),
        "frames": len(err),
    }


def distance_bins(err: np.ndarray, dist: np.ndarray, edges=DISTANCE_BINS) -> list[dict]:
    """Error summaries per distance bin [lo, hi)."""
    out = []
    for lo, hi in zip(edges[:-1], edges[1:], strict=True):
        m = (dist >= lo) & (dist < hi)
        out.append(
            {"min_m": lo, "max_m": None if hi == float("inf") else hi} | error_summary(err[m])
        )
    return out


def _build_detector(spec: str, track: Track, camera: Camera, scene, sigma_px, miss_rate, seed):
    name, _ = parse_spec(spec)
    if name == "oracle":
        bodies = scene.gate_bodies if scene is not None else None
        return OracleDetector(
            track, camera, sigma_px=sigma_px, miss_rate=miss_rate, seed=seed, gate_bodies=bodies
        )
    return make_detector(spec)


def evaluate_estimator(
    track: str | Track | None = "ten-gates",
    detector: str = "oracle",
    seed: int = 0,
    *,
    quad: QuadParams | None = None,
    config: EstimatorConfig | None = None,
    odometry: OdometryConfig | None = None,
    pixel_noise: float = 0.0,
    miss_rate: float = 0.0,
    map_error_m: float = 0.3,
    map_yaw_error_deg: float = 5.0,
    render: bool = True,
    closed_loop: bool = True,
    max_time_s: float | None = None,
    plot_path: str | os.PathLike | None = None,
    pilot: Callable | None = None,
    record: list | None = None,
) -> dict:
    """Fly ``track`` once and report the error of the estimated next-gate position.

    Args:
        track: built-in name, TOML path or Track (None: the default track).
        detector: ``oracle`` or a registered image detector spec (``opencv``, ``cnn[:PATH]``).
        seed: seed of the env, the odometry noise, the map displacement and the oracle's noise.
        quad: the quadrotor (camera included); default QuadParams().
        config: estimator configuration (its mode selects map-aided or map-free).
        odometry: odometry noise and drift.
        pixel_noise: oracle only: corner noise σ, pixels.
        miss_rate: oracle only: probability of missing a gate in view.
        map_error_m, map_yaw_error_deg: map-aided: σ of the prior map's displacement.
        render: render camera frames (oracle visibility from the mask); False: the oracle uses
            geometry only (fast; image detectors need frames).
        closed_loop: the pilot flies on the estimate (True) or on ground truth (False).
        max_time_s: episode time limit (None: the env's default).
        plot_path: also write a PNG of error against distance there.
        pilot: ``f(obs (15,), gate_yaw) -> action (4,)``; default the scripted controller.
        record: when given, the estimator's inputs are appended to it for replay (benchmarks):
            ``("prior", Track | None)`` first, then ``("update", odom, detections)`` per frame and
            ``("predict", odom, None)`` per control step between frames.

    Returns:
        the report: the ARCHITECTURE.md eval-estimator fields plus distance bins, counts and flight.
    """
    wall0 = time.perf_counter()
    name, _ = parse_spec(detector)
    det: Detector | None = None
    if name != "oracle":
        det = make_detector(detector)  # fails early on an unknown name or missing weights
        if not render:
            raise ValueError(f"detector {name} needs rendered frames (render=True)")
    base = resolve_track(track)
    quad = quad or QuadParams()
    config = config or config_for_detector(name)
    camera = Camera.from_params(quad.camera)
    env = make_env("pybullet", config=EnvConfig(track=base, quad=quad, max_episode_s=max_time_s))
    scene = None
    try:
        obs, _ = env.reset(seed=seed)
        flown = env.unwrapped.track
        if render:
            from icarus_vision.render.scene import Scene

            scene = Scene(flown, camera)
        if det is None:
            det = _build_detector(detector, flown, camera, scene, pixel_noise, miss_rate, seed)
        prior = None
        if config.mode == "map-aided":
            prior = displaced_map(flown, map_error_m, map_yaw_error_deg, seed)
        estimator = GateEstimator(camera, config, prior)
        if record is not None:
            record.append(("prior", prior))
        odo = SimulatedOdometry(odometry, seed=seed + 1)
        if pilot is None:
            from icarus_vision.policy.scripted import ScriptedController

            ctrl = ScriptedController(quad)

            def pilot(o, yaw):
                return ctrl.act(o[None], np.array([yaw]))[0]

        rec = _fly(
            env, scene, det, estimator, odo, pilot, obs, quad.camera.rate_hz, closed_loop, record
        )
    finally:
        env.close()
        if scene is not None:
            scene.close()
    err, dist = np.array(rec["err"]), np.array(rec["dist"])
    frames = len(err)
    info = rec["info"]
    report = {
        "detector": name,
        "track": base.name,
        "seed": seed,
        "mode": config.mode,
        "closed_loop": closed_loop,
        "pixel_noise_px": pixel_noise if name == "oracle" else None,
        "map_error_m": map_error_m if config.mode == "map-aided" else None,
        "frames": frames,
        "detection_rate": round(float(np.mean(rec["n_det"]) if frames else 0.0), 4),
        "update_rate": round(float(np.mean(rec["measured"]) if frames else 0.0), 4),
        "rel_gate_error_m": {k: v for k, v in error_summary(err).items() if k != "frames"},
        "within_5m": error_summary(err[dist <= 5.0]),
        "by_distance": distance_bins(err, dist),
        "target_agreement": round(float(np.mean(rec["agree"])) if frames else 0.0, 4),
        "ms_per_frame": round(1e3 * float(np.mean(rec["cost"])), 4) if frames else None,
        "ms_per_frame_p95": round(1e3 * float(np.percentile(rec["cost"], 95)), 4)
        if frames
        else None,
        "ms_per_predict": round(1e3 * float(np.mean(rec["pcost"])), 4) if rec["pcost"] else None,
        "counts": dict(sorted(estimator.counts.items())),
        "gates_passed": info["gates_passed"],
        "gates_total": info["gates_total"],
        "finished": bool(info["all_gates_passed"] and not info["crashed"]),
        "crashed": bool(info["crashed"]),
        "crash_reason": info["crash_reason"],
        "sim_time_s": round(info["time"], 3),
        "wall_time_s": round(time.perf_counter() - wall0, 3),
    }
    if plot_path is not None:
        from icarus_vision.estimator.plots import plot_error_vs_distance

        title = f"{base.name} · {name} · {config.mode}"
        plot_error_vs_distance(plot_path, dist, err, title=title)
    return report


def _fly(env, scene, det, estimator, odo, pilot, obs, rate_hz, closed_loop, record) -> dict:
    """The loop of :func:`evaluate_estimator`: one call per control step, a frame at the camera rate."""
    core = env.unwrapped.core
    frame_dt = 1.0 / rate_hz
    next_frame = 0.0
    rec = {"err": [], "dist": [], "n_det": [], "measured": [], "agree": [], "cost": [], "pcost": []}
    oracle = isinstance(det, OracleDetector)
    info = None
    while True:
        t = float(core.t[0])
        state = env.state
        od = odo.measure_state(t, state)
        if t + 1e-9 >= next_frame:
            while next_frame <= t + 1e-9:
                next_frame += frame_dt
            pos, quat = state.pos[0], state.quat[0]
            frame = scene.render(pos, quat) if scene is not None else None
            if oracle:
                det.set_pose(pos, quat, frame)
                dets = det._detect(None) if frame is None else det.detect(frame.rgb)
            else:
                dets = det.detect(frame.rgb)
            if record is not None:
                record.append(("update", od, dets))
            t0 = time.perf_counter()
            est = estimator.update(od, dets)
            rec["cost"].append(time.perf_counter() - t0)
            truth = core.target_gate()[0][0] - pos
            rec["err"].append(float(np.linalg.norm(est.rel_world - truth)))
            rec["dist"].append(float(np.linalg.norm(truth)))
            rec["n_det"].append(len(dets) > 0)
            rec["measured"].append(est.measured)
            rec["agree"].append(est.target == int(core.target[0]))
        else:
            if record is not None:
                record.append(("predict", od, None))
            t0 = time.perf_counter()
            est = estimator.predict(od)
            rec["pcost"].append(time.perf_counter() - t0)
        if closed_loop:
            action = pilot(fill_observation(obs, est), est.yaw)
        else:
            action = pilot(obs, float(core.target_gate()[1][0]))
        obs, _, term, trunc, info = env.step(action)
        if term or trunc:
            break
    rec["info"] = info
    return rec
