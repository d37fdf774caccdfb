from __future__ import annotations

import numpy as np
import pytest

from icarus_vision.policy.scripted import ScriptedController, fly
from icarus_vision.sim.config import EnvConfig
from icarus_vision.sim.env import BatchedDroneRacingEnv
from icarus_vision.sim.vec_env import BatchedRacingVecEnv


@pytest.mark.parametrize("track", ["single-gate", "ten-gates", "grand-prix"])
def test_scripted_controller_completes_builtin_tracks(make, track):
    result = fly(make(track=track), seed=0)
    assert result["all_gates_passed"] and not result["crashed"], result["crash_reason"]
    assert len(result["lap_times"]) == 1 and result["lap_times"][0] > 0


def test_a_finish_is_timed_where_the_last_gate_plane_was_crossed():
    """The lap ends within its last control step, where the flight crossed the gate's plane (as a
    timing gate reads it), not at the step's end: between the two positions either side of it."""
    env = BatchedDroneRacingEnv(track="single-gate")
    result = fly(env, seed=0)
    assert result["all_gates_passed"]
    dt, (gx, _, _) = env.config.dt, env.track.gates[0].pos  # single-gate's gate faces +x
    x = result["positions"][:, 0]
    k = int(np.flatnonzero(x >= gx)[0])  # the first position past the plane
    crossed = (k - 1 + (gx - x[k - 1]) / (x[k] - x[k - 1])) * dt
    assert result["time"] == pytest.approx(k * dt)
    assert result["finish_time"] == pytest.approx(crossed, abs=1e-9)
    assert result["lap_times"] == [pytest.approx(crossed, abs=1e-9)]
    assert result["time"] - dt < result["finish_time"] < result["time"]


def test_scripted_controller_is_batched_and_flies_random_tracks():
    n = 32
    vec = BatchedRacingVecEnv(n, EnvConfig(random_tracks=True, num_gates=5))
    vec.seed(0)
    obs = vec.reset()
    ctrl = ScriptedController(vec.config.quad)
    first = [None] * n
    for _ in range(1500):
        actions = ctrl.act_env(vec, obs)
        assert actions.shape == (n, 4) and np.all(np.abs(actions) <= 1)
        obs, _, done, infos = vec.step(actions)
        for i in np.flatnonzero(done):
            first[i] = first[i] or infos[i]
        if all(first):
            break
    success = np.mean([f["all_gates_passed"] for f in first])
    assert success >= 0.9


def test_scripted_batch_equals_single():
    ctrl = ScriptedController()
    obs = np.random.default_rng(0).normal(0, 2, (5, 15))
    yaw = np.linspace(-3, 3, 5)
    batch = ctrl.act(obs, yaw)
    single = np.stack([ctrl.act(obs[i], yaw[i])[0] for i in range(5)])
    np.testing.assert_allclose(batch, single, atol=1e-6)
