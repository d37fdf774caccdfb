"""Batched quadrotor dynamics: collective thrust and body-rate commands (CTBR) for N drones.

Model (world z up, body FLU, quaternions stored x, y, z, w as in PyBullet and SciPy):

* action a ∈ [-1, 1]⁴ -> thrust command T_c = (a0 + 1)/2 · T_max, rate command ω_c = a[1:] · ω_max;
* thrust and body rates follow their commands with a first-order lag ``motor_tau`` (the rate
  controller is ideal: torque τ = J (ω_c − ω)/τ_eff + ω × Jω, which gives exactly that lag);
* forces: thrust along body z, gravity, linear body-frame drag on the airspeed v − v_wind;
* integration: semi-implicit Euler in physics sub-steps, the lag in exact exponential form.

The PyBullet backend applies the same thrust, drag and torque (``body_wrench``), so both backends
share one model and differ only in the integrator and collision query.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from icarus_vision.sim.quad import GRAVITY, QuadParams


@dataclass
class QuadState:
    """State of N drones (mutable arrays, updated in place).

    Attributes:
        pos: (N, 3) world position of the centre of mass, m.
        vel: (N, 3) world velocity, m/s.
        quat: (N, 4) attitude, unit quaternion x, y, z, w (body -> world).
        omega: (N, 3) body angular velocity, rad/s.
        thrust: (N,) actual collective thrust, N.
    """

    pos: np.ndarray
    vel: np.ndarray
    quat: np.ndarray
    omega: np.ndarray
    thrust: np.ndarray

    @classmethod
    def zeros(cls, n: int) -> QuadState:
        q = np.zeros((n, 4))
        q[:, 3] = 1.0
        return cls(np.zeros((n, 3)), np.zeros((n, 3)), q, np.zeros((n, 3)), np.zeros(n))

    def copy(self) -> QuadState:
        return QuadState(
            *(a.copy() for a in (self.pos, self.vel, self.quat, self.omega, self.thrust))
        )

    def take(self, idx) -> QuadState:
        return QuadState(
            *(a[idx].copy() for a in (self.pos, self.vel, self.quat, self.omega, self.thrust))
        )

    def put(self, idx, other: QuadState) -> None:
        for name in ("pos", "vel", "quat", "omega", "thrust"):
            getattr(self, name)[idx] = getattr(other, name)


@dataclass
class QuadBatchParams:
    """Per-drone physical parameters after domain randomisation.

    Attributes:
        mass: (N,) kg.
        thrust_max: (N,) N.
        inertia: (3,) kg m² (shared).
        max_rate: (3,) rad/s.
        drag: (N, 3) N/(m/s), body frame.
        motor_tau: (N,) s, the thrust and rate lag.
        radius: m.
    """

    mass: np.ndarray
    thrust_max: np.ndarray
    inertia: np.ndarray
    max_rate: np.ndarray
    drag: np.ndarray
    motor_tau: np.ndarray
    radius: float

    @classmethod
    def from_quad(cls, quad: QuadParams, n: int) -> QuadBatchParams:
        return cls(
            mass=np.full(n, quad.mass),
            thrust_max=np.full(n, quad.thrust_max),
            inertia=np.array(quad.inertia, float),
            max_rate=np.array(quad.max_rate, float),
            drag=np.tile(np.array(quad.drag, float), (n, 1)),
            motor_tau=np.full(n, quad.motor_tau),
            radius=quad.radius,
        )


# R = M · vec(q qᵀ): each rotation entry is a fixed combination of the quaternion's products
# (homogeneous form, exact for unit quaternions), so one matmul converts a whole batch.
_Q2R = np.zeros((16, 9))
for _r, _terms in enumerate(
    [
        ((3, 3, 1), (0, 0, 1), (1, 1, -1), (2, 2, -1)),  # R00 = ww + xx - yy - zz
        ((0, 1, 2), (3, 2, -2)),  # R01 = 2(xy - wz)
        ((0, 2, 2), (3, 1, 2)),  # R02 = 2(xz + wy)
        ((0, 1, 2), (3, 2, 2)),  # R10 = 2(xy + wz)
        ((3, 3, 1), (0, 0, -1), (1, 1, 1), (2, 2, -1)),  # R11 = ww - xx + yy - zz
        ((1, 2, 2), (3, 0, -2)),  # R12 = 2(yz - wx)
        ((0, 2, 2), (3, 1, -2)),  # R20 = 2(xz - wy)
        ((1, 2, 2), (3, 0, 2)),  # R21 = 2(yz + wx)
        ((3, 3, 1), (0, 0, -1), (1, 1, -1), (2, 2, 1)),  # R22 = ww - xx - yy + zz
    ]
):
    for _a, _b, _c in _terms:
        _Q2R[4 * _a + _b, _r] += _c


def quat_to_rot(q: np.ndarray) -> np.ndarray:
    """(N, 4) x, y, z, w unit quaternions -> (N, 3, 3) rotation matrices (body -> world)."""
    n = q.shape[0]
    return ((q[:, :, None] * q[:, None, :]).reshape(n, 16) @ _Q2R).reshape(n, 3, 3)


def cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise cross product of (N, 3) arrays (cheaper than np.cross on small batches)."""
    return a[:, _C1] * b[:, _C2] - a[:, _C2] * b[:, _C1]


_C1 = np.array([1, 2, 0])
_C2 = np.array([2, 0, 1])


def quat_to_rpy(q: np.ndarray) -> np.ndarray:
    """(N, 4) x, y, z, w -> (N, 3) ZYX Euler angles roll, pitch, yaw in radians."""
    x, y, z, w = q[:, 0], q[:, 1], q[:, 2], q[:, 3]
    roll = np.arctan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
    pitch = np.arcsin(np.clip(2 * (w * y - z * x), -1.0, 1.0))
    yaw = np.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
    return np.stack((roll, pitch, yaw), axis=-1)


def rpy_to_quat(rpy: np.ndarray) -> np.ndarray:
    """(N, 3) ZYX Euler roll, pitch, yaw -> (N, 4) x, y, z, w."""
    rpy = np.atleast_2d(rpy)
    cr, sr = np.cos(rpy[:, 0] / 2), np.sin(rpy[:, 0] / 2)
    cp, sp = np.cos(rpy[:, 1] / 2), np.sin(rpy[:, 1] / 2)
    cy, sy = np.cos(rpy[:, 2] / 2), np.sin(rpy[:, 2] / 2)
    return np.stack(
        (
            sr * cp * cy - cr * sp * sy,
            cr * sp * cy + sr * cp * sy,
            cr * cp * sy - sr * sp * cy,
            cr * cp * cy + sr * sp * sy,
        ),
        axis=-1,
    )


# Hamilton product q ⊗ p = M · vec(q pᵀ), quaternions x, y, z, w.
_QMUL = np.zeros((16, 4))
for _k, _terms in enumerate(
    [
        ((3, 0, 1), (0, 3, 1), (1, 2, 1), (2, 1, -1)),  # x = w px + x pw + y pz - z py
        ((3, 1, 1), (0, 2, -1), (1, 3, 1), (2, 0, 1)),  # y = w py - x pz + y pw + z px
        ((3, 2, 1), (0, 1, 1), (1, 0, -1), (2, 3, 1)),  # z = w pz + x py - y px + z pw
        ((3, 3, 1), (0, 0, -1), (1, 1, -1), (2, 2, -1)),  # w = w pw - x px - y py - z pz
    ]
):
    for _a, _b, _c in _terms:
        _QMUL[4 * _a + _b, _k] += _c


def quat_mul(q: np.ndarray, r: np.ndarray) -> np.ndarray:
    """Row-wise Hamilton product q ⊗ r of (N, 4) x, y, z, w quaternions."""
    n = q.shape[0]
    return (q[:, :, None] * r[:, None, :]).reshape(n, 16) @ _QMUL


def quat_integrate(
    q: np.ndarray, omega_body: np.ndarray, dt: float, normalize: bool = True
) -> np.ndarray:
    """Rotate attitudes by body rates over dt (exact for constant ω): q ⊗ exp(ω dt / 2).

    Args:
        q: (N, 4) x, y, z, w.
        omega_body: (N, 3) rad/s, body frame.
        normalize: renormalise the result (the product of unit quaternions drifts only by rounding).

    Returns:
        (N, 4) new quaternions.
    """
    rate = np.sqrt(np.einsum("ij,ij->i", omega_body, omega_body))
    half = 0.5 * dt * rate
    # sin(half)/|ω|, stable for small rates.
    k = np.where(rate > 1e-9, np.sin(half) / np.maximum(rate, 1e-12), 0.5 * dt)
    dq = np.empty_like(q)
    dq[:, :3] = omega_body * k[:, None]
    dq[:, 3] = np.cos(half)
    out = quat_mul(q, dq)
    if normalize:
        out /= np.sqrt(np.einsum("ij,ij->i", out, out))[:, None]
    return out


def action_to_commands(
    action: np.ndarray, params: QuadBatchParams
) -> tuple[np.ndarray, np.ndarray]:
    """Map actions (N, 4) in [-1, 1] to thrust commands (N,) in N and rate commands (N, 3) in rad/s."""
    thrust_cmd = (action[:, 0] + 1.0) * 0.5 * params.thrust_max
    rate_cmd = action[:, 1:] * params.max_rate
    return thrust_cmd, rate_cmd


def lag_gain(dt: float, tau: np.ndarray) -> np.ndarray:
    """Exact discrete gain of first-order lags with time constants ``tau`` (N,) over dt."""
    return 1.0 - np.exp(-dt / np.asarray(tau, float))


def drag_force(rot: np.ndarray, vel: np.ndarray, wind: np.ndarray, drag: np.ndarray) -> np.ndarray:
    """World-frame drag force (N, 3) on the airspeed, with drag (N, 3) diagonal in the body frame."""
    air_b = np.matmul((vel - wind)[:, None, :], rot)  # (N, 1, 3): Rᵀ (v − w) as a row
    return np.matmul(rot, (air_b * -drag[:, None, :]).transpose(0, 2, 1))[:, :, 0]


def gyro_torque(inertia: np.ndarray, omega: np.ndarray) -> np.ndarray:
    """ω × Jω (N, 3), body frame, for a diagonal J (3,) and body rates ω (N, 3): the torque a rate
    controller adds so that the rates follow its command alone."""
    return (inertia[_C2] - inertia[_C1]) * omega[:, _C1] * omega[:, _C2]


def body_wrench(
    state: QuadState,
    thrust_cmd: np.ndarray,
    rate_cmd: np.ndarray,
    wind: np.ndarray,
    params: QuadBatchParams,
    dt: float,
    rot: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Forces and torques one physics sub-step applies, for a backend that integrates itself.

    ``rot`` (N, 3, 3) may be passed when the caller already has the attitude as a matrix.

    Returns:
        thrust_next: (N,) thrust after the lag update, N.
        force_world: (N, 3) thrust + drag, world frame (gravity not included), N.
        torque_world: (N, 3) rate-controller torque, world frame, N m.
    """
    k = lag_gain(dt, params.motor_tau)
    thrust = state.thrust + (thrust_cmd - state.thrust) * k
    rot = quat_to_rot(state.quat) if rot is None else rot
    force = rot[:, :, 2] * thrust[:, None] + drag_force(rot, state.vel, wind, params.drag)
    j, w = params.inertia, state.omega
    torque = j * (rate_cmd - w) * (k / dt)[:, None] + gyro_torque(j, w)
    return thrust, force, np.matmul(rot, torque[:, :, None])[:, :, 0]


def step_substeps(
    state: QuadState,
    thrust_cmd: np.ndarray,
    rate_cmd: np.ndarray,
    wind: np.ndarray,
    params: QuadBatchParams,
    dt: float,
    substeps: int,
    ground_clamp: np.ndarray | None = None,
    accel: np.ndarray | None = None,
) -> np.ndarray:
    """Advance N drones in place by ``substeps`` physics steps of ``dt``.

    Args:
        state: updated in place.
        thrust_cmd: (N,) N; rate_cmd: (N, 3) rad/s; wind: (N, 3) world air velocity, m/s.
        ground_clamp: (N,) bool; where True the drone rests on the ground (z >= radius) instead of
            sinking through it (used before take-off).
        accel: (N, 3) world acceleration added to every sub-step, m/s² (a model's estimate of
            what it does not know; None: nothing).

    Returns:
        (substeps, N, 3) positions after each sub-step (for collision checks).
    """
    k = lag_gain(dt, params.motor_tau)
    inv_m = 1.0 / params.mass[:, None]
    g = np.array([0.0, 0.0, -GRAVITY])
    if accel is not None:
        g = g + accel
    trail = np.empty((substeps, state.pos.shape[0], 3))
    for s in range(substeps):
        state.thrust += (thrust_cmd - state.thrust) * k
        state.omega += (rate_cmd - state.omega) * k[:, None]
        rot = quat_to_rot(state.quat)
        acc = (
            rot[:, :, 2] * state.thrust[:, None] + drag_force(rot, state.vel, wind, params.drag)
        ) * inv_m
        acc += g
        state.vel += acc * dt
        state.pos += state.vel * dt
        state.quat = quat_integrate(state.quat, state.omega, dt, normalize=s == substeps - 1)
        if ground_clamp is not None:
            low = ground_clamp & (state.pos[:, 2] < params.radius)
            if low.any():
                state.pos[low, 2] = np.broadcast_to(params.radius, low.shape)[low]
                state.vel[low, 2] = np.maximum(state.vel[low, 2], 0.0)
        trail[s] = state.pos
    return trail
