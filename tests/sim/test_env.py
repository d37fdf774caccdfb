"""DroneRacingEnv contract over every built-in backend, and the batched VecEnv."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env as gym_check_env
from stable_baselines3.common.env_checker import check_env as sb3_check_env

import icarus_vision  # noqa: F401  (registers IcarusRace-v0)
from icarus_vision.sim.config import EnvConfig, RandomizationConfig
from icarus_vision.sim.dynamics import QuadState
from icarus_vision.sim.env import BatchedDroneRacingEnv
from icarus_vision.sim.pybullet_backend import PyBulletDroneRacingEnv
from icarus_vision.sim.registration import make_env
from icarus_vision.sim.vec_env import BatchedRacingVecEnv
from icarus_vision.sim.wrappers import GateRelativeObsWrapper


@pytest.mark.filterwarnings("ignore::UserWarning")
def test_gymnasium_and_sb3_checkers(backend):
    env = gym.make("IcarusRace-v0", backend=backend, track="three-gates").unwrapped
    gym_check_env(env)  # includes reset/step seed determinism
    sb3_check_env(env, warn=True)
    env.close()


def test_seed_determinism_with_randomisation(make):
    cfg = EnvConfig(
        random_tracks=True, num_gates=3, randomization=RandomizationConfig(enabled=True)
    )
    runs = []
    for _ in range(2):
        env = make(config=cfg)
        obs, _ = env.reset(seed=123)
        traj = [obs]
        rng = np.random.default_rng(0)
        for _ in range(50):
            obs, r, term, trunc, _ = env.step(rng.uniform(-1, 1, 4))
            traj.append(obs)
            if term or trunc:
                break
        runs.append((np.array(traj), env.track, float(env.core.params.mass[0])))
    np.testing.assert_array_equal(runs[0][0], runs[1][0])
    assert runs[0][1] == runs[1][1] and runs[0][2] == runs[1][2]
    env = make(config=cfg)
    env.reset(seed=124)
    assert env.track != runs[0][1]


def test_backends_agree_from_the_same_state():
    envs = [make_env(b, track="single-gate") for b in ("batched", "pybullet", "mujoco")]
    rng = np.random.default_rng(3)
    hover = envs[0].config.quad.hover_thrust_action
    actions = np.clip(
        np.c_[hover + rng.normal(0.05, 0.1, 100), rng.normal(0, 0.25, (100, 3))], -1, 1
    )
    ends = []
    for env in envs:
        env.reset(seed=0)
        st = QuadState.zeros(1)
        st.pos[0], st.vel[0], st.thrust[0] = (-2.0, 1.0, 3.0), (1.0, 0.5, 0.0), 4.9
        st.omega[0] = (0.5, -0.3, 0.2)
        env.core.taken_off[0] = True
        env.set_state(st)
        for a in actions:  # 2 s
            obs, _, term, trunc, _ = env.step(a)
            assert not (term or trunc)
        ends.append(obs[:3])
        env.close()
    # PyBullet integrates the same wrench; MuJoCo flies its own rate loop and integrator.
    assert np.linalg.norm(ends[0] - ends[1]) < 0.10
    assert np.linalg.norm(ends[0] - ends[2]) < 0.10, ends


def test_n_batched_drones_equal_n_single_envs():
    n = 6
    cfg = EnvConfig(
        random_tracks=True, num_gates=3, randomization=RandomizationConfig(enabled=True)
    )
    vec = BatchedRacingVecEnv(n, cfg)
    vec.seed(11)
    obs = vec.reset()
    singles = [BatchedDroneRacingEnv(cfg) for _ in range(n)]
    obs_s = np.stack([e.reset(seed=11 + i)[0] for i, e in enumerate(singles)])
    np.testing.assert_array_equal(obs, obs_s)
    rng = np.random.default_rng(0)
    dones = 0
    for _ in range(300):
        a = rng.uniform(-1, 1, (n, 4))
        a[:, 0] = 0.3 * a[:, 0] - 0.25
        obs, rew, done, infos = vec.step(a)
        for i, e in enumerate(singles):
            o, r, term, trunc, info = e.step(a[i])
            assert done[i] == (term or trunc)
            assert rew[i] == np.float32(r)
            if done[i]:
                dones += 1
                np.testing.assert_array_equal(infos[i]["terminal_observation"], o)
                assert infos[i]["gates_passed"] == info["gates_passed"]
                o, _ = e.reset()
            np.testing.assert_array_equal(obs[i], o)
    assert dones > 0  # auto-reset was exercised


def test_random_and_extreme_actions_never_produce_nan():
    vec = BatchedRacingVecEnv(
        100, EnvConfig(random_tracks=True, randomization=RandomizationConfig(enabled=True))
    )
    vec.seed(0)
    vec.reset()
    rng = np.random.default_rng(1)
    extremes = np.array([-1.0, 1.0, -1e9, 1e9, 0.0, 1e-300, -5.0])
    for k in range(100):  # 100 drones x 100 steps = 10,000 actions
        a = rng.uniform(-3, 3, (100, 4)) if k % 2 else rng.choice(extremes, (100, 4))
        obs, rew, _, infos = vec.step(a)
        assert np.all(np.isfinite(obs)) and np.all(np.isfinite(rew))
        assert np.all(np.isfinite(vec.state.quat)) and np.all(np.isfinite(vec.state.vel))
    env = PyBulletDroneRacingEnv(track="single-gate")
    env.reset(seed=0)
    for k in range(500):
        a = rng.choice(extremes, 4) if k % 2 else rng.uniform(-3, 3, 4)
        obs, r, term, trunc, _ = env.step(a)
        assert np.all(np.isfinite(obs)) and np.isfinite(r)
        if term or trunc:
            env.reset()
    env.close()


def test_bad_actions_raise_value_error(make):
    env = make(track="single-gate")
    with pytest.raises(RuntimeError, match="reset"):
        env.step([0, 0, 0, 0])
    env.reset(seed=0)
    for bad, match in [
        ([0, 0, 0], "shape"),
        (np.zeros((2, 4)), "shape"),
        ([0, np.nan, 0, 0], "NaN or inf"),
        ([np.inf, 0, 0, 0], "NaN or inf"),
    ]:
        with pytest.raises(ValueError, match=match):
            env.step(bad)
    vec = BatchedRacingVecEnv(3, track="single-gate")
    vec.reset()
    with pytest.raises(ValueError, match=r"\(3, 4\)"):
        vec.step(np.zeros((2, 4)))


def test_out_of_range_actions_are_clipped():
    a, b = BatchedDroneRacingEnv(track="single-gate"), BatchedDroneRacingEnv(track="single-gate")
    a.reset(seed=0)
    b.reset(seed=0)
    for _ in range(10):
        oa, *_ = a.step([7.0, -3.0, 2.0, 1.5])
        ob, *_ = b.step([1.0, -1.0, 1.0, 1.0])
    np.testing.assert_array_equal(oa, ob)


def test_info_reward_terms_and_observation(make):
    env = make(track="single-gate")
    obs, info = env.reset(seed=0)
    assert obs.shape == (15,) and obs.dtype == np.float32
    np.testing.assert_allclose(obs[12:15], np.array([5.0, 0.0, 2.0]) - obs[:3], atol=1e-6)
    for _ in range(10):  # thrust spins up from zero, then the drone climbs toward the gate
        obs, r, term, trunc, info = env.step([0.2, 0, 0, 0])
    for key in ("gates_passed", "all_gates_passed", "crashed", "crash_reason", "lap_time"):
        assert key in info
    terms = info["reward_terms"]
    assert set(terms) == {"progress", "gate", "crash", "attitude"}
    assert r == pytest.approx(sum(terms.values()))
    assert terms["progress"] > 0  # climbing toward the gate


def test_time_limit_truncates():
    env = BatchedDroneRacingEnv(track="single-gate", max_episode_s=1.0)
    env.reset(seed=0)
    ends = [env.step([-1.0, 0, 0, 0])[2:4] for _ in range(50)]
    assert ends[-1] == (False, True)  # truncated at exactly 1 s = 50 steps
    assert not any(term or trunc for term, trunc in ends[:-1])


def test_set_num_gates_through_env_method():
    vec = BatchedRacingVecEnv(4, track="ten-gates")
    vec.reset()
    assert vec.core.n_pass.tolist() == [10] * 4
    vec.env_method("set_num_gates", 3)
    vec.reset()
    assert vec.core.n_pass.tolist() == [3] * 4
    rnd = BatchedRacingVecEnv(2, random_tracks=True, num_gates=1)
    rnd.reset()
    rnd.env_method("set_num_gates", 5)
    rnd.reset()
    assert rnd.core.n_pass.tolist() == [5, 5]
    env = make_env("batched", track="ten-gates")
    env.set_num_gates(1)
    env.reset(seed=0)
    assert len(env.track.gates) == 1


def test_domain_randomisation_is_seeded_and_off_by_default():
    vec = BatchedRacingVecEnv(8, track="five-gates")
    vec.seed(0)
    vec.reset()
    assert np.all(vec.core.params.mass == 0.5) and np.all(vec.core.wind_const == 0)
    r = RandomizationConfig(enabled=True, mass_pct=0.2, wind_mps=3.0)
    vec = BatchedRacingVecEnv(64, track="five-gates", randomization=r)
    vec.seed(0)
    vec.reset()
    m = vec.core.params.mass
    assert m.min() >= 0.4 and m.max() <= 0.6 and m.std() > 0.03
    assert np.linalg.norm(vec.core.wind_const, axis=1).max() <= 3.0
    gates0 = vec.core.g_pos[0, :5].copy()
    assert not np.allclose(gates0, vec.core.g_pos[1, :5])  # gate jitter differs per drone


def test_dynamics_randomisation_leaves_the_older_draws_alone():
    def drones(**extra):
        r = RandomizationConfig(enabled=True, **extra)
        vec = BatchedRacingVecEnv(32, random_tracks=True, num_gates=5, randomization=r)
        vec.seed(7)
        vec.reset()
        return vec.core

    base, dyn = drones(), drones(motor_tau_pct=0.2, drag_pct=0.3)
    assert np.all(base.params.motor_tau == 0.03) and np.all(base.params.drag == (0.3, 0.3, 0.5))
    # the new draws come last: mass, wind, tracks and gates are the episodes they were
    np.testing.assert_array_equal(base.params.mass, dyn.params.mass)
    np.testing.assert_array_equal(base.wind_const, dyn.wind_const)
    np.testing.assert_array_equal(base.g_pos, dyn.g_pos)
    tau, drag = dyn.params.motor_tau, dyn.params.drag
    assert 0.024 <= tau.min() and tau.max() <= 0.036 and tau.std() > 0.002
    assert drag.shape == (32, 3) and np.all(np.abs(drag / (0.3, 0.3, 0.5) - 1) <= 0.3)
    assert len(np.unique(drag[:, 0])) == 32


def test_gate_relative_obs_wrapper_matches_body_frame_env():
    world = GateRelativeObsWrapper(BatchedDroneRacingEnv(track="three-gates"))
    body = BatchedDroneRacingEnv(track="three-gates", gate_obs_frame="body")
    ow, _ = world.reset(seed=0)
    ob, _ = body.reset(seed=0)
    for _k in range(30):
        a = [0.1, 0.2, -0.1, 0.3]
        ow, *_ = world.step(a)
        ob, *_ = body.step(a)
    np.testing.assert_allclose(ow, ob, atol=1e-4)
    assert not np.allclose(ow[12:15], body.core.target_gate()[0][0] - ob[:3])


def test_extended_observation():
    env = BatchedDroneRacingEnv(track="three-gates", observation="extended")
    obs, _ = env.reset(seed=0)
    assert obs.shape == (21,) and env.observation_space.shape == (21,)
    g = env.track.gates
    np.testing.assert_allclose(obs[15:18], g[0].normal, atol=1e-6)
    np.testing.assert_allclose(obs[18:21], np.array(g[1].pos) - obs[:3], atol=1e-5)
    vec = BatchedRacingVecEnv(2, track="three-gates", observation="extended")
    assert vec.reset().shape == (2, 21)


def test_racing_observation_adds_the_opening_and_the_gate_after_direction(tmp_path):
    from icarus_vision.sim.track import Gate, Track

    track = Track(
        "sizes",
        (
            Gate((5.0, 0.0, 2.0), size=0.8),
            Gate((10.0, 3.0, 2.5), yaw_deg=40.0, size=1.3),
            Gate((14.0, 6.0, 2.0), yaw_deg=90.0, size=1.5),
        ),
        start_pos=(0.0, 0.0, 2.0),
    )
    env = BatchedDroneRacingEnv(track=track, observation="racing")
    obs, _ = env.reset(seed=0)
    assert obs.shape == (25,) and env.observation_space.shape == (25,)
    ext, _ = BatchedDroneRacingEnv(track=track, observation="extended").reset(seed=0)
    np.testing.assert_allclose(obs[:21], ext, atol=1e-6)
    assert obs[21] == pytest.approx(0.8)
    np.testing.assert_allclose(obs[22:25], track.gates[1].normal, atol=1e-6)
    # Body frame: the direction turns with the drone, the opening side does not.
    body, _ = BatchedDroneRacingEnv(track=track, observation="racing", gate_obs_frame="body").reset(
        seed=0
    )
    assert body[21] == pytest.approx(0.8)
    assert np.linalg.norm(body[22:25]) == pytest.approx(1.0, abs=1e-5)
    assert BatchedRacingVecEnv(3, track=track, observation="racing").reset().shape == (3, 25)
    with pytest.raises(ValueError, match="observation must be one of basic, extended, racing"):
        EnvConfig(observation="full")


def test_episode_reward_terms_sum_to_the_return():
    vec = BatchedRacingVecEnv(4, track="single-gate", max_episode_s=1.0)
    vec.seed(0)
    vec.reset()
    for _ in range(50):
        _, _, done, infos = vec.step(np.tile([0.3, 0.0, 0.1, 0.0], (4, 1)))
    assert done.all()
    for info in infos:
        terms = info["episode_reward_terms"]
        assert set(terms) == {"progress", "gate", "crash", "attitude"}
        assert sum(terms.values()) == pytest.approx(info["episode"]["r"], rel=1e-6, abs=1e-6)
