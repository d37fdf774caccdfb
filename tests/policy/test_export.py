from __future__ import annotations

import json

import numpy as np
import pytest

from icarus_vision.policy.export import export_sb3_policy, load_policy
from icarus_vision.policy.pilots import default_policy_path


class FakeModel:
    """A real SB3 PPO policy built on a tiny VecEnv, without training."""

    def __init__(self, observation="basic"):
        from stable_baselines3 import PPO

        from icarus_vision.policy.features import FeatureVecEnv
        from icarus_vision.sim.vec_env import BatchedRacingVecEnv

        env = FeatureVecEnv(BatchedRacingVecEnv(2, track="single-gate", observation=observation))
        self.model = PPO("MlpPolicy", env, n_steps=8, batch_size=16, device="cpu", seed=0)
        self.policy = self.model.policy


@pytest.mark.parametrize("observation, dim", [("basic", 15), ("extended", 21), ("racing", 25)])
def test_export_round_trip(tmp_path, observation, dim):
    fake = FakeModel(observation)
    path = export_sb3_policy(fake.model, tmp_path / "p", observation, {"name": "t"})
    pol = load_policy(path, expect_obs_dim=dim)
    obs = np.random.default_rng(0).normal(0, 3, (10, dim)).astype(np.float32)
    from icarus_vision.policy.features import obs_to_features

    want, _ = fake.model.predict(obs_to_features(obs), deterministic=True)
    np.testing.assert_allclose(pol.act(obs), want, atol=1e-5)
    assert pol.act(obs[0]).shape == (4,)
    with pytest.raises(ValueError, match=f"expects observations of {dim}"):
        pol.act(np.zeros((1, 7)))


def test_load_errors_name_the_file_and_mismatch(tmp_path):
    fake = FakeModel()
    path = export_sb3_policy(fake.model, tmp_path / "p", "basic")
    with pytest.raises(ValueError, match="observes 15 entries but this run provides 21"):
        load_policy(path, expect_obs_dim=21)
    with pytest.raises(FileNotFoundError, match="missing.safetensors"):
        load_policy(tmp_path / "missing.safetensors")
    bad = tmp_path / "bad"
    (tmp_path / "bad.safetensors").write_bytes(b"garbage")
    (tmp_path / "bad.json").write_text((tmp_path / "p.json").read_text())
    with pytest.raises(ValueError, match="bad.safetensors: corrupt"):
        load_policy(bad)
    desc = json.loads((tmp_path / "p.json").read_text())
    desc["obs_dim"] = 17
    (tmp_path / "p.json").write_text(json.dumps(desc))
    with pytest.raises(ValueError, match="p.json: observation of 17 entries does not match"):
        load_policy(path)
    desc["obs_dim"] = 21
    (tmp_path / "p.json").write_text(json.dumps(desc))
    with pytest.raises(ValueError, match="observation 'basic' does not have 21 entries"):
        load_policy(path)
    desc["obs_dim"] = 15
    desc["action"] = "motor_speeds"
    (tmp_path / "p.json").write_text(json.dumps(desc))
    with pytest.raises(ValueError, match="action convention"):
        load_policy(path)


def test_shipped_default_policy_loads():
    if not default_policy_path().is_file():
        pytest.skip("no shipped policy yet")
    pol = load_policy(default_policy_path())
    assert pol.act(np.zeros(pol.obs_dim, np.float32)).shape == (4,)
