"""crash_replay: an episode can start again shortly before an earlier crash, exactly as it was."""

from __future__ import annotations

import numpy as np
import pytest

from icarus_vision.sim.config import EnvConfig, RandomizationConfig
from icarus_vision.sim.vec_env import BatchedRacingVecEnv

# full thrust and a steady pitch: the drone leaves the course's bounds after a second or two
AWAY = np.array([[1.0, 0.0, 0.3, 0.0]])
RND = RandomizationConfig(enabled=True, mass_pct=0.2, thrust_pct=0.2, wind_mps=2.0, gust_mps=1.0)


def env_with(replay: float, seed: int = 3) -> BatchedRacingVecEnv:
    cfg = EnvConfig(
        random_tracks=True, num_gates=4, layout_difficulty=1.0, crash_replay=replay,
        randomization=RND,
    )  # fmt: skip
    env = BatchedRacingVecEnv(1, cfg)
    env.seed(seed)
    env.reset()
    return env


def fly_episode(env) -> tuple[list[np.ndarray], list[float], dict]:
    """One episode of ``AWAY``: positions and clock after each step, and its last info."""
    pos, times = [], []
    while True:
        _, _, done, infos = env.step(AWAY)
        if done[0]:
            return pos, times, infos[0]
        pos.append(env.state.pos[0].copy())
        times.append(float(env.core.t[0]))


def test_a_crash_is_kept_with_the_state_flown_shortly_before_it():
    env = env_with(0.5)
    _, times, info = fly_episode(env)
    assert info["crashed"] and not info["replayed"]
    t_crash = info["time"]
    assert t_crash > 1.0  # long enough to have a moment to keep
    if not env.core.crashes:  # the new episode may already have taken it
        assert env.core.replayed[0]
        moment_t = float(env.core.t[0])
    else:
        (moment,) = env.core.crashes
        moment_t = float(moment["t"])
    # within the asked range (to the nearest 0.2 s snapshot)
    assert 0.4 - 1e-9 <= t_crash - moment_t <= 1.6 + 0.2 + 1e-9
    assert any(abs(moment_t - t) < 1e-9 for t in times)


def test_the_replayed_start_flies_the_crashed_flight_again():
    env = env_with(0.5)
    flights = [fly_episode(env)]  # (positions, clock, last info) of each episode
    checked_older = 0
    for _ in range(40):
        if not env.core.replayed[0]:
            flights.append(fly_episode(env))
            continue
        t0, p0 = float(env.core.t[0]), env.state.pos[0].copy()
        # the flight it came from: one that was at this place at this time (a replay of it
        # is there too)
        src = [
            (f, k)
            for f, (pos, times, _) in enumerate(flights)
            for k in range(len(times))
            if abs(times[k] - t0) < 1e-9 and np.allclose(pos[k], p0, atol=1e-12)
        ]
        assert src
        f, k = src[0]
        pos, _, first = flights[f]
        again = fly_episode(env)
        assert again[2]["replayed"] and again[2]["crashed"]
        # the same drone (mass, thrust, wind) and clock, the same actions: the same flight
        np.testing.assert_allclose(np.array(again[0]), np.array(pos[k + 1 :]), atol=1e-9)
        assert again[2]["time"] == pytest.approx(first["time"])
        assert again[2]["crash_reason"] == first["crash_reason"]
        assert again[2]["gates_passed"] == first["gates_passed"]
        checked_older += f < len(flights) - 1  # a crash older than the last episode's
        flights.append(again)
        if checked_older >= 2:
            break
    assert checked_older >= 2


def test_no_replay_before_any_crash_and_none_without_the_option():
    a, b = env_with(0.0, seed=11), env_with(0.7, seed=11)
    # the first episode is drawn identically: the option draws nothing until a crash is kept
    np.testing.assert_array_equal(a.core.g_pos, b.core.g_pos)
    for _ in range(4):
        fly_episode(a)
        assert not a.core.replayed[0]
    assert a.core.crashes == []


def test_bad_settings_are_refused():
    with pytest.raises(ValueError, match="crash_replay"):
        EnvConfig(random_tracks=True, crash_replay=1.0)
    with pytest.raises(ValueError, match="crash_replay_s"):
        EnvConfig(random_tracks=True, crash_replay=0.3, crash_replay_s=(0.0, 1.0))
    with pytest.raises(ValueError, match="crash_replay_s"):
        EnvConfig(random_tracks=True, crash_replay=0.3, crash_replay_s=(1.0, 3.0))


def test_a_train_config_passes_it_to_the_training_env_only():
    from icarus_vision.policy.config import SPECIALIST, config_from_dict
    from icarus_vision.policy.train import make_train_env

    cfg = config_from_dict({"curriculum": {"crash_replay": 0.4}})
    assert cfg.curriculum.crash_replay == 0.4
    with pytest.raises(ValueError, match="crash_replay"):
        config_from_dict({"curriculum": {"crash_replay": 1.5}})
    env = make_train_env(SPECIALIST, 2, 3, seed=0, crash_replay=cfg.curriculum.crash_replay)
    assert env.unwrapped.core.cfg.crash_replay == 0.4
    assert make_train_env(SPECIALIST, 2, 3, seed=0).unwrapped.core.cfg.crash_replay == 0.0
