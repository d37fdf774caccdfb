"""The closed race loop: physics -> camera -> detector -> estimator -> observation -> pilot -> action.

Each control step (the quadrotor's 50 Hz by default): the physics backend advances; at the camera
rate the FPV image is rendered from the true pose and handed to the detector; the detections reach
the estimator ``latency_frames`` camera frames later (default one), fused with the odometry reading
of the moment the image was taken; between frames the estimator predicts through odometry. The
observation is the odometry reading plus the estimated next gate; the pilot acts on it.

``detector="oracle"`` skips camera, detector and estimator: the observation carries the true gate
position, so perception errors can be told apart from control errors.
"""

from __future__ import annotations

import copy
from collections import deque
from dataclasses import dataclass, field

import numpy as np

from icarus_vision.estimator.config import EstimatorConfig
from icarus_vision.estimator.estimator import GateEstimator
from icarus_vision.estimator.odometry import SimulatedOdometry
from icarus_vision.gate_detect.base import Detector
from icarus_vision.gate_detect.registry import make_detector, parse_spec
from icarus_vision.render.camera import Camera
from icarus_vision.render.randomize import Visuals, apply_sensor_noise
from icarus_vision.sim.dynamics import QuadState, quat_to_rpy
from icarus_vision.sim.observation import OBS_DIMS, heading_vectors
from icarus_vision.sim.track import Track


@dataclass
class LoopRecord:
    """What one race produced, step by step (for the report, the plot and the video)."""

    t: list[float] = field(default_factory=list)
    pos: list[np.ndarray] = field(default_factory=list)
    speed: list[float] = field(default_factory=list)
    frames: int = 0
    detected: int = 0
    rel_err: list[float] = field(default_factory=list)
    gate_dist: list[float] = field(default_factory=list)
    """Per camera frame (not the oracle): true distance to the next gate, m."""
    target_ok: list[bool] = field(default_factory=list)
    """Per camera frame (not the oracle): whether the estimator's next gate is the true one."""
    video: list[np.ndarray] = field(default_factory=list)
    info: dict = field(default_factory=dict)


class Perception:
    """Camera, detector and estimator for one drone, with detection latency."""

    def __init__(self, detector: str | Detector, prior: Track, camera: Camera, scene, seed: int, latency_frames: int,
                 config: EstimatorConfig | None = None, look: Visuals | None = None) -> None:  # fmt: skip
        self.camera, self.scene, self.look = camera, scene, look
        self.noise_rng = np.random.default_rng([seed, 37])  # the sensor's pixel noise
        self.detector = make_detector(detector) if isinstance(detector, str) else detector
        self.estimator = GateEstimator(camera, config or EstimatorConfig(), prior)
        self.odometry = SimulatedOdometry(seed=seed + 1)
        self.pending: deque = deque()
        self.latency = latency_frames
        self.estimate = None

    def frame(self, od, pos, quat) -> tuple[np.ndarray, list]:
        """Render and detect at the current true pose; fuse what is due."""
        if self.look is None:
            rgb = self.scene.render(pos, quat).rgb
        else:  # the race's drawn light and sensor
            rgb = self.scene.render(pos, quat, self.look.lighting).rgb
            rgb = apply_sensor_noise(rgb, self.look.sensor, self.noise_rng)
        dets = self.detector.detect(rgb)
        self.pending.append((od, dets))
        if len(self.pending) > self.latency:
            od_then, dets_then = self.pending.popleft()
            self.estimator.update(od_then, dets_then)
        self.estimate = self.estimator.predict(od)
        return rgb, dets

    def step(self, od) -> None:
        self.estimate = self.estimator.predict(od)


def observation_from(od, rel_world: np.ndarray, extra: np.ndarray | None = None) -> np.ndarray:
    """The policy observation from an odometry reading and a gate vector (world frame)."""
    rpy = quat_to_rpy(np.asarray(od.quat)[None])[0]
    parts = [od.pos, od.vel, rpy, od.omega, rel_world]
    if extra is not None:
        parts.append(extra)
    return np.concatenate(parts).astype(np.float32)


def fly_loop(env, pilot, obs_dim: int, *, detector: str | Detector, camera: Camera, scene, seed: int,
             prior: Track, latency_frames: int = 1, on_frame=None,
             estimator: EstimatorConfig | None = None, look: Visuals | None = None,
             open_loop: bool = False, lookahead=None) -> LoopRecord:  # fmt: skip
    """Fly one episode of a single-drone env (already reset) with perception in the loop.

    Args:
        pilot: ``f(obs (obs_dim,), gate_yaw) -> action (4,)``; gate_yaw is the next gate's heading
            (estimated, or true with the oracle).
        obs_dim: 15 (basic), 21 (extended) or 25 (racing): the gate direction, the gate after and
            the opening side come from the estimator's map, which vision keeps corrected.
        prior: the estimator's map of the track (the nominal layout: with randomisation the real
            gates are displaced from it and vision must correct them).
        detector: a detector spec (``cnn[:PATH]``, ``opencv``, ``oracle``) or a built Detector.
        on_frame: ``f(rgb, detections, estimate, state)`` called at each camera frame (video).
        estimator: estimator configuration (noise model of the detector, filter gates).
        look: the drawn look of the world (``scene`` built with its style and distractors): its
            light renders every frame and its sensor effects degrade it.
        open_loop: the pilot flies on the true observation (as with the oracle) while camera,
            detector and estimator run alongside and are recorded: every perception variant then
            sees the same flight and the same images.
    """
    core = env.unwrapped.core
    oracle = isinstance(detector, str) and parse_spec(detector)[0] == "oracle"
    per = (
        None
        if oracle
        else Perception(detector, prior, camera, scene, seed, latency_frames, estimator, look)
    )
    frame_dt = 1.0 / camera_rate(env)
    next_frame = 0.0
    rec = LoopRecord()
    truth_obs = core.observe(env.state)[0]
    while True:
        t = float(core.t[0])
        state = env.state
        rel_true = core.target_gate()[0][0] - state.pos[0]
        if oracle:
            obs = truth_obs
            if t + 1e-9 >= next_frame:
                next_frame += frame_dt
                rec.frames += 1
                rec.detected += 1
                rec.rel_err.append(0.0)
                if on_frame is not None:
                    on_frame(None, [], None, state)
            od = None
        else:
            od = per.odometry.measure_state(t, state)
            if t + 1e-9 >= next_frame:
                while next_frame <= t + 1e-9:
                    next_frame += frame_dt
                rgb, dets = per.frame(od, state.pos[0], state.quat[0])
                rec.frames += 1
                rec.detected += bool(dets)
                rec.rel_err.append(float(np.linalg.norm(per.estimate.rel_world - rel_true)))
                rec.gate_dist.append(float(np.linalg.norm(rel_true)))
                rec.target_ok.append(int(per.estimate.target) == int(core.target[0]))
                if on_frame is not None:
                    on_frame(rgb, dets, per.estimate, state)
            else:
                per.step(od)
            if open_loop:
                obs = truth_obs
            else:
                extra = extra_from_estimate(per.estimate, per.estimator, od, obs_dim)
                obs = observation_from(od, per.estimate.rel_world, extra)
        on_truth = oracle or open_loop
        gate_yaw = float(core.target_gate()[1][0]) if on_truth else per.estimate.yaw
        if lookahead is None:
            action = pilot(obs, gate_yaw)
        elif on_truth:
            action = lookahead.act(core, env.state, obs[None])[0]
        else:
            belief = believed_race(core, per.estimator, per.estimate, od, prior)
            action = lookahead.act(belief, odometry_state(od, env.state), obs[None])[0]
        obs_full, _, term, trunc, info = env.step(action)
        truth_obs = obs_full
        rec.t.append(float(core.t[0]))
        rec.pos.append(env.state.pos[0].copy())
        rec.speed.append(float(np.linalg.norm(env.state.vel[0])))
        if term or trunc:
            rec.info = info
            return rec


def believed_race(core, estimator, estimate, od, prior: Track):
    """The race of a single-drone ``core`` as the drone knows it: every gate where the
    estimator's map puts it (map-free: the prior), the next one where the estimate puts it."""
    belief = copy.copy(core)  # shares the clocks and counters; the gate arrays below are new
    mapped = estimator.passage_map() if hasattr(estimator, "passage_map") else None
    if mapped is None:
        mapped = (
            np.array([g.pos for g in prior.passages], float),
            np.array([g.yaw for g in prior.passages]),
        )
    pos, yaw = mapped
    m = min(len(pos), core.g_pos.shape[1])
    belief.g_pos, belief.g_yaw = core.g_pos.copy(), core.g_yaw.copy()
    belief.g_pos[0, :m], belief.g_yaw[0, :m] = pos[:m], yaw[:m]
    j = int(core.target[0])
    if j < m:
        belief.g_pos[0, j] = np.asarray(od.pos) + estimate.rel_world
        belief.g_yaw[0, j] = estimate.yaw
    belief.g_cos, belief.g_sin = np.cos(belief.g_yaw), np.sin(belief.g_yaw)
    return belief


def odometry_state(od, truth: QuadState) -> QuadState:
    """A one-drone state from an odometry reading (the motors' thrust from their telemetry)."""
    return QuadState(np.asarray(od.pos, float)[None], np.asarray(od.vel, float)[None],
                     np.asarray(od.quat, float)[None], np.asarray(od.omega, float)[None],
                     truth.thrust.copy())  # fmt: skip


def camera_rate(env) -> float:
    return float(env.unwrapped.config.quad.camera.rate_hz)


def extra_from_estimate(est, estimator, od, obs_dim: int) -> np.ndarray | None:
    """Observation slots after 15 from the estimate: the passage direction and the gate after
    (extended, 15:21), the opening side and the gate after's direction (racing, 21:25). The gate
    after comes from the estimator's map; map-free, it repeats the next gate."""
    if obs_dim == OBS_DIMS["basic"]:
        return None
    after = estimator.gate_after_position() if hasattr(estimator, "gate_after_position") else None
    rel_after = (after - od.pos) if after is not None else est.rel_world
    parts = [heading_vectors(np.array([est.yaw]))[0], rel_after]
    if obs_dim == OBS_DIMS["racing"]:
        after_yaw = estimator.gate_after_yaw() if hasattr(estimator, "gate_after_yaw") else None
        yaw = est.yaw if after_yaw is None else after_yaw
        parts += [[est.size], heading_vectors(np.array([yaw]))[0]]
    return np.concatenate(parts)
