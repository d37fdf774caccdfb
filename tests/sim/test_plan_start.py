"""plan_start: an episode can start from a state of the fixed track's time-optimal plan."""

from __future__ import annotations

from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pytest

from icarus_vision.sim.builtin import resolve_track
from icarus_vision.sim.config import EnvConfig, RandomizationConfig
from icarus_vision.sim.vec_env import BatchedRacingVecEnv

TRACK = resolve_track("single-gate").with_laps(2)  # one gate at (5, 0, 2), flown twice
GATE = np.array([5.0, 0.0, 2.0])
RND = RandomizationConfig(
    enabled=True, mass_pct=0.2, thrust_pct=0.2, gate_pos_jitter_m=0.0, gate_yaw_jitter_deg=0.0
)


def fake_plan() -> SimpleNamespace:
    """A plan-shaped record (not a flyable one): a line from the start to the gate (node 10,
    passage 0), a loop 2 m around it (nodes 11-19), the gate again (node 20, passage 1)."""
    k = np.arange(21)
    line = np.linspace([0.0, 0.0, 0.2], GATE, 11)
    angle = np.linspace(0.0, 2 * np.pi, 11)[1:-1]
    loop = GATE + 2.0 * np.stack([np.sin(angle), np.zeros(9), 1 - np.cos(angle)], axis=1)
    quat = np.random.default_rng(0).normal(size=(21, 4))
    return SimpleNamespace(
        t=0.1 * k, pos=np.concatenate([line, loop, GATE[None]]),
        vel=np.stack([k, -k, 2 * k], axis=1).astype(float),
        quat=quat / np.linalg.norm(quat, axis=1, keepdims=True),
        rates=np.stack([k, k, -k], axis=1) * 0.1, thrust=4.0 + 0.1 * k,
        gate_nodes=np.array([10, 20]),
    )  # fmt: skip


def env_with(plan_start: float, n: int = 64, seed: int = 5, plan=True) -> BatchedRacingVecEnv:
    env = BatchedRacingVecEnv(n, EnvConfig(track=TRACK, plan_start=plan_start, randomization=RND))
    if plan:
        env.core.set_plan(fake_plan())
    env.seed(seed)
    env.reset()
    return env


def test_starts_are_plan_nodes_between_passages_with_the_plans_state_clock_and_laps():
    plan, env = fake_plan(), env_with(0.5)
    core, state = env.core, env.state
    from_plan = core.replayed.copy()
    assert 0 < from_plan.sum() < env.num_envs  # both kinds, about half each
    assert np.all(state.pos[~from_plan] == [0.0, 0.0, 0.2]) and np.all(core.t[~from_plan] == 0)
    seen = set()
    for i in np.flatnonzero(from_plan):
        (node,) = np.flatnonzero(np.isclose(plan.t, core.t[i]))
        seen.add(int(node))
        assert node not in (0, 10, 20)  # neither the start nor a passage
        assert np.linalg.norm(plan.pos[node] - GATE) >= 0.5  # clear of the gate either side
        for name, ref in (("pos", plan.pos), ("vel", plan.vel), ("quat", plan.quat)):
            assert getattr(state, name)[i] == pytest.approx(ref[node])
        assert state.omega[i] == pytest.approx(plan.rates[node])
        scaled = plan.thrust[node] * core.params.mass[i] / core.cfg.quad.mass
        assert state.thrust[i] == pytest.approx(min(scaled, core.params.thrust_max[i]))
        assert core.taken_off[i]
        if node < 10:  # first lap: nothing passed yet
            assert core.target[i] == 0 and core.lap_times[i] == [] and core.lap_start[i] == 0
        else:  # second lap: the first lap's time is the plan's crossing time
            assert core.target[i] == 1 and core.lap_times[i] == pytest.approx([1.0])
            assert core.lap_start[i] == pytest.approx(1.0) and core.n_laps[i] == 1
    assert any(k < 10 for k in seen) and any(k > 10 for k in seen)


def test_a_plan_started_drone_races_on_from_its_node():
    """Its passage and lap are counted on the plan's clock; the episode is marked replayed so
    the curriculum does not count it as a start."""
    env = env_with(0.99, n=8)
    core = env.core
    i = int(np.flatnonzero(core.target == 0)[0])  # a drone on the line towards the gate
    env.state.pos[i] = GATE - [0.1, 0.0, 0.0]
    env.state.vel[i] = [10.0, 0.0, 0.0]
    t0 = core.t[i]
    _, _, done, infos = env.step(np.zeros((8, 4)))
    assert not done[i], infos[i]
    assert core.target[i] == 1
    assert core.lap_times[i] == pytest.approx([t0 + 0.01], abs=0.002)  # 0.1 m at 10 m/s


def test_plan_start_zero_draws_nothing_and_episodes_stay_the_same():
    plain = BatchedRacingVecEnv(8, EnvConfig(track=TRACK, randomization=RND))
    plain.seed(5)
    plain.reset()
    env = env_with(0.0, n=8)
    assert not env.core.replayed.any()
    for a, b in zip(plain.state.__dict__.values(), env.state.__dict__.values(), strict=True):
        assert np.array_equal(a, b)
    assert np.array_equal(plain.core.params.mass, env.core.params.mass)


def test_a_track_cut_short_by_the_curriculum_starts_from_the_start():
    two_gates = replace(TRACK, gates=TRACK.gates * 2, laps=1)  # the plan's two passages
    env = BatchedRacingVecEnv(8, EnvConfig(track=two_gates, plan_start=0.99, randomization=RND))
    env.core.set_plan(fake_plan())
    env.core.set_num_gates(1)  # the first gate only: the plan's second passage is not flown
    env.seed(5)
    env.reset()
    assert not env.core.replayed.any() and np.all(env.core.t == 0)


def test_plan_starts_refused_without_a_plan_or_a_fixed_track():
    with pytest.raises(ValueError, match="plan_start"):
        EnvConfig(track=TRACK, plan_start=1.0)
    with pytest.raises(RuntimeError, match="set_plan"):
        env_with(0.5, plan=False)
    env = BatchedRacingVecEnv(1, EnvConfig(random_tracks=True))
    with pytest.raises(ValueError, match="fixed track"):
        env.core.set_plan(fake_plan())
    one_lap = BatchedRacingVecEnv(1, EnvConfig(track=resolve_track("single-gate")))
    with pytest.raises(ValueError, match="2 passages for 1"):
        one_lap.core.set_plan(fake_plan())
    two_laps = BatchedRacingVecEnv(1, EnvConfig(track=TRACK))
    with pytest.raises(ValueError, match="no node keeps"):  # the loop stays within 4 m
        two_laps.core.set_plan(fake_plan(), clearance_m=5.0)
