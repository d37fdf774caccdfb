"""Perception noise on the gate observation (obs[12:15]) during training.

The race flies on the estimator's output, not on ground truth, so the policy trains on a noisy gate
vector: each step the detector "sees" the next gate with probability 1 − miss(d) and then the gate's
estimated world position is redrawn around the truth with standard deviation σ(d) per axis (d = the
distance to the gate); on a miss the last estimate is held (as the estimator carries it through
odometry) and the relative vector is recomputed from the drone's current position. A new target
gate always starts with a fresh draw (the map prior): an ordinary detection's, or with a map error
set, the truth moved uniformly within ± that per axis (a race's map is the nominal layout, and
randomisation moves the real gates off it). With ``out_of_view`` set, a gate outside the
camera's field of view is never seen (the detector cannot find what the camera does not show), so
a policy that turns the camera away from the next gate flies on a stale estimate.

σ(d) and miss(d) come from a detector error model file written by ``eval-detector`` when one is
given, otherwise from a linear parametric default.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from stable_baselines3.common.vec_env import VecEnv, VecEnvWrapper

from icarus_vision.policy.config import PerceptionNoiseConfig
from icarus_vision.sim.dynamics import quat_to_rot, rpy_to_quat
from icarus_vision.sim.quad import CameraParams

GATE = slice(12, 15)
HEADING = slice(15, 18)  # extended: the next gate's passage direction (world, horizontal unit)
AFTER = slice(18, 21)  # extended: the gate after, relative to the drone (world)


@dataclass(frozen=True)
class ErrorModel:
    """Gate-position error as a function of distance (piecewise linear between bin centres).

    Attributes:
        distance_m: (B,) bin centres, metres, increasing.
        sigma_m: (B,) per-axis standard deviation of the gate position error, metres.
        miss_rate: (B,) probability that the gate is not detected.
    """

    distance_m: tuple[float, ...]
    sigma_m: tuple[float, ...]
    miss_rate: tuple[float, ...]

    def __post_init__(self) -> None:
        d, s, m = (np.asarray(x, float) for x in (self.distance_m, self.sigma_m, self.miss_rate))
        if not (len(d) == len(s) == len(m) >= 1):
            raise ValueError(
                "error model: distance_m, sigma_m and miss_rate need the same length >= 1"
            )
        if not (np.all(np.isfinite(d)) and np.all(np.diff(d) > 0)):
            raise ValueError("error model: distance_m must be finite and increasing")
        if np.any(~np.isfinite(s)) or np.any(s < 0) or np.any((m < 0) | (m > 1)):
            raise ValueError("error model: sigma_m must be >= 0 and miss_rate in [0, 1]")

    def sigma(self, dist: np.ndarray) -> np.ndarray:
        return np.interp(dist, self.distance_m, self.sigma_m)

    def miss(self, dist: np.ndarray) -> np.ndarray:
        return np.interp(dist, self.distance_m, self.miss_rate)

    @classmethod
    def parametric(cls, cfg: PerceptionNoiseConfig, max_dist: float = 30.0) -> ErrorModel:
        d = np.array([0.0, max_dist])
        return cls(
            tuple(d),
            tuple(cfg.sigma_base_m + cfg.sigma_per_m * d),
            tuple(np.clip(cfg.miss_base + cfg.miss_per_m * d, 0, 1)),
        )

    @classmethod
    def load(cls, path: str | Path) -> ErrorModel:
        """Read the ``error_model`` JSON written by eval-detector (keys distance_m, sigma_m, miss_rate)."""
        path = Path(path)
        if not path.is_file():
            raise FileNotFoundError(f"{path}: error model file not found")
        try:
            data = json.loads(path.read_text())
            return cls(tuple(data["distance_m"]), tuple(data["sigma_m"]), tuple(data["miss_rate"]))
        except (json.JSONDecodeError, KeyError, TypeError) as e:
            raise ValueError(f"{path}: not a valid error model ({e})") from None

    @classmethod
    def from_config(cls, cfg: PerceptionNoiseConfig) -> ErrorModel:
        return cls.load(cfg.error_model) if cfg.error_model else cls.parametric(cfg)


def gate_in_view(obs: np.ndarray, camera: CameraParams) -> np.ndarray:
    """(N,) bool: the next gate's centre lies inside the camera's image.

    Args:
        obs: (N, D) observations: rpy in obs[:, 6:9], world-frame gate vector in obs[:, 12:15].
        camera: the FPV camera (field of view, resolution, uptilt).
    """
    rot = quat_to_rot(rpy_to_quat(obs[:, 6:9].astype(np.float64)))
    body = np.einsum("nji,nj->ni", rot, obs[:, GATE].astype(np.float64))  # world -> body (FLU)
    tilt = np.radians(camera.uptilt_deg)
    c, s = np.cos(tilt), np.sin(tilt)
    forward = c * body[:, 0] + s * body[:, 2]
    up = -s * body[:, 0] + c * body[:, 2]
    tan_h = np.tan(np.radians(camera.hfov_deg) / 2)
    tan_v = tan_h * camera.height / camera.width
    ahead = forward > 1e-6
    f = np.where(ahead, forward, 1.0)
    return ahead & (np.abs(body[:, 1] / f) <= tan_h) & (np.abs(up / f) <= tan_v)


class PerceptionNoise:
    """Batched noise state for N drones; ``apply`` maps true observations to perceived ones."""

    def __init__(
        self,
        model: ErrorModel,
        n: int,
        seed: int | None = None,
        camera: CameraParams | None = None,
        map_error_m: float = 0.0,
        map_yaw_error_deg: float = 0.0,
        map_share: float = 1.0,
        bias_m: float = 0.0,
        bias_share: float = 1.0,
    ) -> None:
        """``camera``: when given, gates outside its field of view are never seen;
        ``map_error_m``: a new target gate's first estimate is the truth moved uniformly within
        ± this per axis (0: an ordinary detection's draw); ``map_yaw_error_deg``: with the
        extended observation, a new target gate's passage direction is turned uniformly within ±
        this until the gate is seen, and the gate after it is off by ± ``map_error_m`` per axis
        (both from the map, as in a race; drawn from a stream of their own); ``map_share``: the
        share of the drones (the first of the batch) that fly with the map's errors, the others
        starting each gate from an ordinary detection (the same draws either way); ``bias_m``:
        every detection of a target gate is off by the same N(0, bias_m²) draw per axis, made
        when the gate becomes the target (a stream of its own, so the other draws stand);
        ``bias_share``: the share of the drones (the first of the batch, so with equal shares the
        same drones as the map's errors) that fly with that bias."""
        self.model = model
        self.map_drones = np.arange(n) < round(map_share * n)
        self.bias_drones = np.arange(n) < round(bias_share * n)
        self.camera = camera
        self.map_error_m = map_error_m
        self.map_yaw_error = np.radians(map_yaw_error_deg)
        self.rng = np.random.default_rng(seed)
        self.map_rng = np.random.default_rng(None if seed is None else [seed, 1])
        self.est = np.zeros((n, 3))
        self.true_prev = np.full((n, 3), np.nan)
        self.yaw_err = np.zeros(n)
        self.after_err = np.zeros((n, 3))
        self.bias_m = bias_m
        self.bias_rng = np.random.default_rng(None if seed is None else [seed, 2])
        self.bias = np.zeros((n, 3))

    def apply(self, obs: np.ndarray, new_episode: np.ndarray | None = None) -> np.ndarray:
        """Perceived observations.

        Args:
            obs: (N, D) true observations with world-frame gate vectors in obs[:, 12:15].
            new_episode: (N,) bool, drones whose episode just (re)started.

        Returns:
            (N, D) float32 copy with obs[:, 12:15] replaced by the perceived gate vector.
        """
        pos = obs[:, 0:3].astype(np.float64)
        true_gate = pos + obs[:, GATE]
        dist = np.linalg.norm(obs[:, GATE], axis=1)
        switched = ~(np.abs(true_gate - self.true_prev) < 1e-3).all(axis=1)
        if new_episode is not None:
            switched |= new_episode
        detected = self.rng.random(len(obs)) >= self.model.miss(dist)
        if self.camera is not None:
            detected &= gate_in_view(obs, self.camera)
        seen = switched | detected
        noise = self.rng.normal(size=(len(obs), 3)) * self.model.sigma(dist)[:, None]
        if self.map_error_m > 0:
            prior = self.rng.uniform(-self.map_error_m, self.map_error_m, size=(len(obs), 3))
            noise = np.where((switched & self.map_drones)[:, None], prior, noise)
        if self.bias_m > 0:
            draw = self.bias_rng.normal(size=(len(obs), 3)) * self.bias_m
            draw *= self.bias_drones[:, None]
            self.bias = np.where(switched[:, None], draw, self.bias)
            noise = noise + self.bias
        self.est = np.where(seen[:, None], true_gate + noise, self.est)
        self.true_prev = true_gate
        out = obs.astype(np.float32, copy=True)
        out[:, GATE] = self.est - pos
        if self.map_yaw_error > 0 and obs.shape[1] >= AFTER.stop:
            n = len(obs)
            yaw = self.map_rng.uniform(-self.map_yaw_error, self.map_yaw_error, n)
            after = self.map_rng.uniform(-self.map_error_m, self.map_error_m, (n, 3))
            yaw, after = yaw * self.map_drones, after * self.map_drones[:, None]
            self.yaw_err = np.where(switched, yaw, np.where(detected, 0.0, self.yaw_err))
            self.after_err = np.where(switched[:, None], after, self.after_err)
            c, s = np.cos(self.yaw_err), np.sin(self.yaw_err)
            hx, hy = obs[:, HEADING.start], obs[:, HEADING.start + 1]
            out[:, HEADING.start] = c * hx - s * hy
            out[:, HEADING.start + 1] = s * hx + c * hy
            out[:, AFTER] += self.after_err
        return out


class PerceptionNoiseVecEnv(VecEnvWrapper):
    """Applies ``PerceptionNoise`` to a VecEnv's observations (world-frame gate vectors)."""

    def __init__(
        self,
        venv: VecEnv,
        model: ErrorModel,
        seed: int | None = None,
        camera: CameraParams | None = None,
        map_error_m: float = 0.0,
        map_yaw_error_deg: float = 0.0,
        map_share: float = 1.0,
        bias_m: float = 0.0,
        bias_share: float = 1.0,
    ) -> None:
        super().__init__(venv)
        self.noise = PerceptionNoise(
            model, venv.num_envs, seed, camera, map_error_m, map_yaw_error_deg, map_share,
            bias_m, bias_share,
        )  # fmt: skip

    def reset(self) -> np.ndarray:
        return self.noise.apply(self.venv.reset(), np.ones(self.num_envs, bool))

    def step_wait(self):
        obs, rew, done, infos = self.venv.step_wait()
        return self.noise.apply(obs, done), rew, done, infos
