from __future__ import annotations

import numpy as np

from icarus_vision.policy.callbacks import CurriculumCallback, RunningMeanStd
from icarus_vision.policy.config import CurriculumConfig


class FakeVecEnv:
    def __init__(self):
        self.calls = []

    def env_method(self, name, *args, **kwargs):
        self.calls.append((name, args))


def info(gates, ok):
    return {"gates_total": gates, "all_gates_passed": ok, "crashed": not ok}


def make_curriculum():
    cb = CurriculumCallback(
        CurriculumConfig(stages=(1, 3, 5, 10), promote_success=0.8, window=100, min_episodes=20),
        verbose=0,
    )
    env = FakeVecEnv()
    cb.venv = env
    return cb, env


def test_curriculum_promotes_when_success_is_high_and_not_before():
    cb, env = make_curriculum()
    for _ in range(19):  # 100 % success but fewer than min_episodes
        assert not cb.record(info(1, True))
    assert cb.stage == 0
    assert cb.record(info(1, True))  # 20th episode at 100 %
    assert cb.stage == 1 and env.calls[-1] == ("set_num_gates", (3,))
    # 70 % success never promotes, however many episodes
    for k in range(300):
        cb.record(info(3, k % 10 < 7))
    assert cb.stage == 1
    # episodes from the previous stage's gate count do not count
    for _ in range(50):
        cb.record(info(1, True))
    assert cb.stage == 1
    for _ in range(100):
        cb.record(info(3, True))
    assert cb.stage == 2 and env.calls[-1] == ("set_num_gates", (5,))


def test_curriculum_stays_at_last_stage():
    cb, env = make_curriculum()
    cb.stage = 3
    for _ in range(200):
        cb.record(info(10, True))
    assert cb.stage == 3 and not env.calls


def test_running_mean_std_matches_numpy_over_all_batches():
    rng = np.random.default_rng(0)
    batches = [
        rng.normal(loc, scale, size)
        for loc, scale, size in [(3, 2, 500), (-1, 0.5, 37), (10, 5, 2000), (0, 1, 1)]
    ]
    rms = RunningMeanStd()
    for b in batches:
        rms.update(b)
    allv = np.concatenate(batches)
    assert rms.count == allv.size
    assert np.isclose(rms.mean, allv.mean()) and np.isclose(rms.var, allv.var())
