"""The MuJoCo backend's own model: built from the quadrotor file, rebuilt per track, flown in a race.

The contract, hover, free fall, rate lag, gate passage and crash tests run on it through the
``backend`` fixture (tests/conftest.py); these check what is MuJoCo's alone.
"""

from __future__ import annotations

from dataclasses import replace

import mujoco
import numpy as np
import pytest

from icarus_vision.racing.runner import run_race
from icarus_vision.sim.builtin import BUILTIN_TRACKS, builtin_track
from icarus_vision.sim.config import EnvConfig, RandomizationConfig
from icarus_vision.sim.dynamics import QuadState
from icarus_vision.sim.mujoco_backend import MuJoCoDroneRacingEnv, model_xml, rate_gain
from icarus_vision.sim.quad import QuadParams
from icarus_vision.sim.registration import make_env


@pytest.mark.parametrize("name", BUILTIN_TRACKS)
def test_every_builtin_track_compiles_with_one_body_per_physical_gate(name):
    track = builtin_track(name)
    m = mujoco.MjModel.from_xml_string(model_xml(track, QuadParams(), 200.0))
    gates = len(track.physical_gates())
    assert m.nbody == 1 + gates + 1  # world, gates, drone
    assert m.ngeom == 1 + 4 * gates + 1  # ground, four bars each, drone sphere
    assert m.opt.timestep == pytest.approx(1 / 200)
    assert m.opt.integrator == mujoco.mjtIntegrator.mjINT_IMPLICIT


def test_the_body_and_actuators_come_from_the_quadrotor_file():
    quad = replace(QuadParams(), mass=0.8, inertia=(0.003, 0.004, 0.006), radius=0.2,
                   motor_tau=0.05, max_rate=(8.0, 9.0, 3.0))  # fmt: skip
    m = mujoco.MjModel.from_xml_string(model_xml(builtin_track("single-gate"), quad, 100.0))
    drone = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "drone")
    assert m.body_mass[drone] == pytest.approx(0.8)
    np.testing.assert_allclose(m.body_inertia[drone], (0.003, 0.004, 0.006))
    assert m.geom_size[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, "drone"), 0] == 0.2
    assert m.actuator_dynprm[0, 0] == pytest.approx(0.05)  # thrust lag
    np.testing.assert_allclose(m.actuator_ctrlrange[0], (0.0, quad.thrust_max))
    np.testing.assert_allclose(m.actuator_ctrlrange[1:, 1], (8.0, 9.0, 3.0))
    gain = m.actuator_gainprm[1:, 0]  # each step closes the exact lag's share of the rate error
    k = gain * m.opt.timestep / (np.array(quad.inertia) + gain * m.opt.timestep)
    np.testing.assert_allclose(k, 1 - np.exp(-m.opt.timestep / 0.05))
    assert np.all(gain > np.array(quad.inertia) / 0.05)  # above J/τ, which lags by about dt/2 more


def test_randomised_dynamics_reach_the_model_each_episode():
    rand = RandomizationConfig(enabled=True, motor_tau_pct=0.2, drag_pct=0.3)
    env = MuJoCoDroneRacingEnv(EnvConfig(track="three-gates", randomization=rand))
    masses = set()
    for seed in range(3):
        env.reset(seed=seed)
        m, p = env.model, env.core.params
        assert m.body_mass[env._body] == p.mass[0]
        assert m.actuator_ctrlrange[0, 1] == p.thrust_max[0]
        assert m.actuator_dynprm[0, 0] == p.motor_tau[0] != QuadParams().motor_tau
        np.testing.assert_allclose(
            m.actuator_gainprm[1:4, 0], rate_gain(p.inertia, p.motor_tau[0], m.opt.timestep)
        )
        masses.add(float(m.body_mass[env._body]))
    assert len(masses) == 3
    env.close()


def test_a_randomised_drone_flies_like_the_numpy_model():
    """Mass, thrust, lag and drag drawn per episode: 2 s of varied commands from the same state
    end within a centimetre on MuJoCo and on the numpy backend (a mass that reached the body but
    not MuJoCo's derived constants once flew 5 cm off in 0.2 s)."""
    rand = RandomizationConfig(enabled=True, motor_tau_pct=0.2, drag_pct=0.3)
    cfg = EnvConfig(track="single-gate", randomization=rand)
    ends = []
    for backend in ("batched", "mujoco"):
        env = make_env(backend, config=cfg)
        env.reset(seed=4)
        rng = np.random.default_rng(3)
        hover = env.config.quad.hover_thrust_action
        actions = np.clip(
            np.c_[hover + rng.normal(0.15, 0.1, 100), rng.normal(0, 0.5, (100, 3))], -1, 1
        )
        st = QuadState.zeros(1)
        st.pos[0], st.vel[0], st.thrust[0], st.omega[0] = (
            (-2, 1, 3),
            (1, 0.5, 0),
            4.9,
            (0.5, -0.3, 0.2),
        )
        env.core.taken_off[0] = True
        env.set_state(st)
        for a in actions:
            obs, *_ = env.step(a)
        ends.append(obs[:6])
    assert np.abs(ends[0] - ends[1]).max() < 0.01, ends


def test_the_world_is_rebuilt_only_when_the_track_changes():
    env = MuJoCoDroneRacingEnv(track="three-gates")
    env.reset(seed=0)
    model = env.model
    env.reset(seed=1)
    assert env.model is model
    env = MuJoCoDroneRacingEnv(EnvConfig(random_tracks=True, num_gates=3))
    env.reset(seed=0)
    model = env.model
    env.reset(seed=1)
    assert env.model is not model


def test_a_race_flies_on_mujoco():
    res = run_race("three-gates", backend="mujoco", detector="oracle", policy="default", seed=0)
    assert res.report["backend"] == "mujoco"
    assert res.report["finished"] and not res.report["crashed"]
