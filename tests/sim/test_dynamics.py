"""Physics checks on both backends: hover, free fall, rate response; rotation helpers."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from icarus_vision.sim.dynamics import (
    QuadState,
    quat_integrate,
    quat_to_rot,
    quat_to_rpy,
    rpy_to_quat,
)
from icarus_vision.sim.quad import GRAVITY, QuadParams


def airborne(env, z=3.0, thrust=None):
    env.reset(seed=0)
    q = env.config.quad
    st = QuadState.zeros(1)
    st.pos[0] = (0.0, 0.0, z)
    st.thrust[0] = q.mass * GRAVITY if thrust is None else thrust
    env.core.taken_off[0] = True
    env.set_state(st)
    return q


def test_hover_holds_altitude(make):
    env = make(track="single-gate")
    q = airborne(env)
    zs = []
    for _ in range(100):  # 2 s at 50 Hz
        obs, *_ = env.step([q.hover_thrust_action, 0, 0, 0])
        zs.append(obs[2])
    assert np.max(np.abs(np.array(zs) - 3.0)) < 0.02


def test_free_fall_matches_g(make):
    env = make(track="single-gate", quad=QuadParams(drag=(0.0, 0.0, 0.0)))
    airborne(env, z=5.0, thrust=0.0)
    for _ in range(25):  # 0.5 s, motors off
        obs, *_ = env.step([-1.0, 0, 0, 0])
    t, dt = 0.5, 1.0 / env.config.physics_hz
    # Semi-implicit Euler: velocity is exact under constant acceleration, position is off by
    # g·t·dt/2 (1.2 cm here), the same in both backends.
    assert obs[5] == pytest.approx(-GRAVITY * t, rel=1e-4)
    assert obs[2] == pytest.approx(5.0 - 0.5 * GRAVITY * t * (t + dt), abs=1e-3)


def test_rate_command_tracked_after_lag(make):
    env = make(track="single-gate")
    q = airborne(env)
    cmd = np.array([0.3, -0.2, 0.5])  # fractions of max_rate
    target = cmd * np.array(q.max_rate)
    obs, *_ = env.step([q.hover_thrust_action, *cmd])
    first = obs[9:12]  # after 20 ms: 1 - exp(-0.02 / 0.03) of the way
    np.testing.assert_allclose(
        first, target * (1 - math.exp(-0.02 / q.motor_tau)), rtol=0.05, atol=0.02
    )
    for _ in range(9):  # 0.2 s = 6.7 time constants
        obs, *_ = env.step([q.hover_thrust_action, *cmd])
    np.testing.assert_allclose(obs[9:12], target, rtol=0.02, atol=0.02)


def test_rotation_helpers_match_scipy():
    r = Rotation.random(50, random_state=1)
    q = r.as_quat()  # x, y, z, w
    np.testing.assert_allclose(quat_to_rot(q), r.as_matrix(), atol=1e-12)
    rpy = quat_to_rpy(q)
    np.testing.assert_allclose(rpy, r.as_euler("ZYX")[:, ::-1], atol=1e-9)
    back = rpy_to_quat(rpy)
    np.testing.assert_allclose(np.abs(np.einsum("ij,ij->i", back, q)), 1.0, atol=1e-12)


def test_quat_integrate_is_exact_for_constant_rate():
    q0 = Rotation.random(5, random_state=2).as_quat()
    w = np.random.default_rng(0).normal(0, 3, (5, 3))
    q = q0.copy()
    for _ in range(100):
        q = quat_integrate(q, w, 0.01)
    want = Rotation.from_quat(q0) * Rotation.from_rotvec(w * 1.0)
    np.testing.assert_allclose(np.abs(np.einsum("ij,ij->i", q, want.as_quat())), 1.0, atol=1e-9)
