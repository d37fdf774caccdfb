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


def scaled_copy(src, dest, factor: float):
    """The exported policy ``src`` with every weight times ``factor``, written as ``dest``."""
    from safetensors.numpy import load_file, save_file

    tensors = {
        k: (v * factor).astype(np.float32) for k, v in load_file(f"{src}.safetensors").items()
    }
    save_file(tensors, f"{dest}.safetensors")
    desc = json.loads(open(f"{src}.json").read())
    desc["meta"] = {"name": dest.name}
    (dest.parent / f"{dest.name}.json").write_text(json.dumps(desc))
    return dest


def test_average_is_the_mean_of_the_weights_and_refuses_other_architectures(tmp_path):
    from icarus_vision.policy.export import average_policies

    src = default_policy_path().with_suffix("")
    a, b = scaled_copy(src, tmp_path / "a", 1.0), scaled_copy(src, tmp_path / "b", 0.5)
    out = average_policies([a, b], tmp_path / "avg", {"name": "average"})
    avg, pa, pb = load_policy(out), load_policy(a), load_policy(b)
    for (wa, ba), (wb, bb), (w, bias) in zip(pa.weights, pb.weights, avg.weights, strict=True):
        np.testing.assert_allclose(wb, 0.5 * wa, rtol=1e-6)
        np.testing.assert_allclose(w, 0.75 * wa, rtol=1e-6)  # (1 + 0.5) / 2
        np.testing.assert_allclose(bias, (ba + bb) / 2, rtol=1e-6)
    assert avg.desc["meta"]["averaged"] == [str(a), str(b)]
    assert avg.features == pa.features and avg.obs_dim == pa.obs_dim
    assert avg.act(np.zeros((3, avg.obs_dim))).shape == (3, 4)
    # a policy of another architecture is named in the refusal
    other = FakeModel("extended").model
    export_sb3_policy(other, tmp_path / "wide", "extended", {"name": "w"})
    with pytest.raises(ValueError, match="wide.*differ"):
        average_policies([a, tmp_path / "wide"], tmp_path / "bad")
    with pytest.raises(ValueError, match="no policies"):
        average_policies([], tmp_path / "none")


def test_average_policy_command_averages_a_runs_last_evaluations(tmp_path):
    from typer.testing import CliRunner

    from icarus_vision.cli import app

    run = tmp_path / "run"
    (run / "evaluated").mkdir(parents=True)
    src = default_policy_path().with_suffix("")
    for i, factor in enumerate((9.0, 1.0, 0.5)):  # the first is left out by --last 2
        scaled_copy(src, run / "evaluated" / f"{(i + 1) * 1000:09d}", factor)
    runner = CliRunner()
    r = runner.invoke(app, ["average-policy", str(run), "--last", "2"])
    assert r.exit_code == 0, r.output
    avg, one = load_policy(run / "average"), load_policy(src)
    np.testing.assert_allclose(avg.weights[0][0], 0.75 * one.weights[0][0], rtol=1e-6)
    assert len(avg.desc["meta"]["averaged"]) == 2
    r = runner.invoke(app, ["average-policy", str(run), "--last", "4"])
    assert r.exit_code == 1 and "evaluated 3 policies" in r.output
    r = runner.invoke(app, ["average-policy", str(tmp_path / "nothing")])
    assert r.exit_code == 1 and "no evaluated policies" in r.output
