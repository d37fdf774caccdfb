"""layout_replay: failed layouts come back, successes and fixed tracks do not, old draws stand."""

from __future__ import annotations

import numpy as np
import pytest

from icarus_vision.policy.callbacks import CurriculumCallback
from icarus_vision.policy.config import CurriculumConfig
from icarus_vision.sim.config import EnvConfig, RandomizationConfig
from icarus_vision.sim.vec_env import BatchedRacingVecEnv

HOVER = np.array([[0.0, 0.0, 0.0, 0.0]])


def gates_of(track) -> np.ndarray:
    return np.array([g.pos for g in track.gates])


def run_episodes(env, n: int) -> list[dict]:
    """Step ``env`` (one drone) until ``n`` episodes ended; their infos and layouts."""
    ended = []
    layout = env.core.layouts[0]
    while len(ended) < n:
        _, _, done, infos = env.step(HOVER)
        if done[0]:
            ended.append({**infos[0], "layout": layout})
            layout = env.core.layouts[0]
    return ended


def timed_out_env(replay: float, **kw) -> BatchedRacingVecEnv:
    """Every episode times out after 0.1 s: each one is a failure."""
    cfg = EnvConfig(
        random_tracks=True, num_gates=4, layout_difficulty=1.0, max_episode_s=0.1,
        layout_replay=replay, **kw,
    )  # fmt: skip
    env = BatchedRacingVecEnv(1, cfg)
    env.seed(5)
    env.reset()
    return env


def test_failed_layouts_are_flown_again_with_the_gates_jittered_afresh():
    rnd = RandomizationConfig(enabled=True, gate_pos_jitter_m=0.3)
    env = timed_out_env(0.5, randomization=rnd)
    episodes = run_episodes(env, 60)
    failed = [e["layout"] for e in episodes]
    replayed = [e for e in episodes if e["replayed"]]
    assert 15 <= len(replayed) <= 45  # about half, once the first failure is in
    for e in replayed:
        # the layout is one failed earlier, not a new draw
        assert any(e["layout"] is f for f in failed[: episodes.index(e)])
    # the flown track is the layout jittered, and a new jitter each time
    env.core.reset_drones(np.array([0]))
    flown, layout = env.core.tracks[0], env.core.layouts[0]
    moved = np.abs(gates_of(flown) - gates_of(layout)).max()
    assert 0 < moved <= 0.3 + 1e-9


def test_finished_layouts_and_fixed_tracks_are_never_replayed():
    env = timed_out_env(0.5)
    env.core.replay.clear()
    # a finished episode adds nothing: the drone is put through every gate by hand
    env.core.target[0] = env.core.n_pass[0]
    _, _, done, infos = env.step(HOVER)
    assert done[0] and infos[0]["all_gates_passed"]
    assert not env.core.replay
    run_episodes(env, 1)  # a timed-out one does
    assert len(env.core.replay) == 1 or env.core.replayed[0]  # kept, or already drawn again
    fixed = BatchedRacingVecEnv(
        1, EnvConfig(track="grand-prix", max_episode_s=0.1, layout_replay=0.5)
    )
    fixed.seed(0)
    fixed.reset()
    assert not any(e["replayed"] for e in run_episodes(fixed, 10))
    assert not fixed.core.replay


def test_without_replay_the_layouts_are_the_old_draws():
    old = timed_out_env(0.0)
    eps = run_episodes(old, 8)
    assert not any(e["replayed"] for e in eps)
    with_replay = timed_out_env(0.5)
    # the first episode draws before any failure: the same layout as without replay
    assert np.array_equal(gates_of(with_replay.core.layouts[0]), gates_of(eps[0]["layout"]))


def test_new_gate_count_or_difficulty_empties_the_buffer():
    env = timed_out_env(0.5)
    run_episodes(env, 5)
    assert env.core.replay
    env.set_num_gates(6)
    assert not env.core.replay
    run_episodes(env, 5)
    assert env.core.replay
    env.set_difficulty(0.5)
    assert not env.core.replay


def test_replayed_episodes_do_not_count_for_promotion():
    cb = CurriculumCallback(CurriculumConfig(stages=(3, 5), min_episodes=1, window=5))
    cb.venv = BatchedRacingVecEnv(1, EnvConfig(random_tracks=True, num_gates=3))
    fresh = {"gates_total": 3, "all_gates_passed": True, "crashed": False, "replayed": False}
    assert not cb.record({**fresh, "replayed": True})
    assert cb.success_rate() == 0.0
    assert cb.record(fresh)
    assert cb.venv.core.num_gates == 5


def test_replay_chance_is_validated():
    with pytest.raises(ValueError, match="layout_replay"):
        EnvConfig(random_tracks=True, layout_replay=1.0)
