"""Simulated odometry: the drone's true state plus configurable white noise and drift.

A real racing drone gets its own pose from visual-inertial odometry: smooth, locally accurate and
slowly drifting away from the true world frame. This model adds a random-walk position bias and a
random-walk heading bias (rotating the attitude about world z) to the true state, plus small white
noise on every reading. The estimator sees only these readings, never the true state.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from icarus_vision.estimator.config import OdometryConfig
from icarus_vision.sim.dynamics import quat_mul


@dataclass(frozen=True)
class OdometryReading:
    """One odometry sample.

    Attributes:
        t: time, s.
        pos: (3,) position, odometry world frame, m.
        vel: (3,) velocity, odometry world frame, m/s.
        quat: (4,) attitude x, y, z, w, body -> odometry world.
        omega: (3,) body angular velocity, rad/s.
    """

    t: float
    pos: np.ndarray
    vel: np.ndarray
    quat: np.ndarray
    omega: np.ndarray


_SHAPES = (("pos", 3), ("vel", 3), ("quat", 4), ("omega", 3))


def check_odometry(odom: OdometryReading) -> None:
    """Raise ValueError when a reading has a non-finite entry, a bad shape or a zero quaternion."""
    for name, n in _SHAPES:
        a = np.asarray(getattr(odom, name), dtype=float)
        if a.shape != (n,):
            raise ValueError(f"odometry {name} must have shape ({n},), got {a.shape}")
        values = a.tolist()  # plain floats: a few numbers, no numpy calls
        if not all(map(math.isfinite, values)):
            raise ValueError(f"odometry {name} is not finite: {values}")
    if not math.isfinite(odom.t):
        raise ValueError(f"odometry time is not finite: {odom.t}")
    if math.hypot(*np.asarray(odom.quat, dtype=float).tolist()) < 1e-6:
        raise ValueError("odometry quaternion has zero norm")


def _small_rotation_quat(rotvec: np.ndarray) -> np.ndarray:
    """(3,) rotation vector -> (4,) quaternion x, y, z, w."""
    angle = float(np.linalg.norm(rotvec))
    if angle < 1e-12:
        return np.array([0.0, 0.0, 0.0, 1.0])
    axis = rotvec / angle
    return np.array([*(axis * math.sin(angle / 2.0)), math.cos(angle / 2.0)])


class SimulatedOdometry:
    """Turns true states into odometry readings with noise and drift (seeded).

    Args:
        config: noise and drift levels.
        seed: seed of the noise generator.
    """

    def __init__(self, config: OdometryConfig | None = None, seed: int | None = 0) -> None:
        self.config = config or OdometryConfig()
        self.rng = np.random.default_rng(seed)
        self.reset()

    def reset(self) -> None:
        """Zero the drift (the odometry frame starts aligned with the world)."""
        self.pos_bias = np.zeros(3)
        self.yaw_bias = 0.0
        self._t: float | None = None

    def measure(
        self, t: float, pos: np.ndarray, vel: np.ndarray, quat: np.ndarray, omega: np.ndarray
    ) -> OdometryReading:
        """The reading for the true state at time ``t`` (shapes as :class:`OdometryReading`).

        Raises:
            ValueError: a non-finite true state.
        """
        truth = OdometryReading(
            float(t),
            np.asarray(pos, float).reshape(3),
            np.asarray(vel, float).reshape(3),
            np.asarray(quat, float).reshape(4),
            np.asarray(omega, float).reshape(3),
        )
        check_odometry(truth)
        c, rng = self.config, self.rng
        dt = 0.0 if self._t is None else max(truth.t - self._t, 0.0)
        self._t = truth.t
        if dt > 0:
            self.pos_bias += rng.normal(0.0, c.pos_drift_m_per_sqrt_s * math.sqrt(dt), 3)
            self.yaw_bias += math.radians(c.yaw_drift_deg_per_sqrt_s) * math.sqrt(dt) * rng.normal()
        att = _small_rotation_quat(rng.normal(0.0, math.radians(c.att_noise_deg), 3))
        yaw = _small_rotation_quat(np.array([0.0, 0.0, self.yaw_bias]))
        q = quat_mul(yaw[None], quat_mul(truth.quat[None] / np.linalg.norm(truth.quat), att[None]))
        return OdometryReading(
            t=truth.t,
            pos=truth.pos + self.pos_bias + rng.normal(0.0, c.pos_noise_m, 3),
            vel=truth.vel + rng.normal(0.0, c.vel_noise_mps, 3),
            quat=q[0],
            omega=truth.omega + rng.normal(0.0, c.rate_noise_radps, 3),
        )

    def measure_state(self, t: float, state, i: int = 0) -> OdometryReading:
        """The reading of drone ``i`` of a :class:`~icarus_vision.sim.dynamics.QuadState`."""
        return self.measure(t, state.pos[i], state.vel[i], state.quat[i], state.omega[i])
