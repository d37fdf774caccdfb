"""The privileged critic: what it reads, that the actor never does, and that runs with it export
ordinary policies and resume."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import torch
from stable_baselines3 import PPO

from icarus_vision.policy.config import RACING, PerceptionNoiseConfig, load_train_config
from icarus_vision.policy.critic import EXTRA_DIM, AsymmetricActorCriticPolicy, privileged_dim
from icarus_vision.policy.export import load_policy
from icarus_vision.policy.features import obs_to_features
from icarus_vision.policy.train import make_train_env, train_policy

TINY = replace(
    RACING,
    privileged_critic=True,
    init=None,
    features="v2",
    init_critic_steps=0,
    ppo=replace(RACING.ppo, num_envs=8, n_steps=32, batch_size=128, n_epochs=1, torch_threads=1),
    checkpoint_every=256,
    eval_every=256,
    eval_episodes=4,
)


def test_the_learner_reads_the_actors_features_then_the_truth_and_the_hidden_parameters():
    noisy = replace(TINY, perception=PerceptionNoiseConfig(sigma_base_m=0.5, sigma_per_m=0.1))
    env = make_train_env(noisy, 6, 3, seed=4)
    plain = make_train_env(replace(noisy, privileged_critic=False), 6, 3, seed=4)
    obs, ref = env.reset(), plain.reset()
    f = env.actor_dim
    assert obs.shape == (6, privileged_dim(f)) == (6, 2 * f + EXTRA_DIM)
    # the actor's block is what a run without the critic gets (same seed, same noise)
    np.testing.assert_allclose(obs[:, :f], ref, atol=1e-6)
    base = env.base
    truth = obs_to_features(base.core.observe(base.state), env.version)
    np.testing.assert_allclose(obs[:, f : 2 * f], truth, atol=1e-5)
    assert not np.allclose(
        obs[:, :f], obs[:, f : 2 * f], atol=1e-3
    )  # the noise is only the actor's
    extra = obs[:, 2 * f :]
    np.testing.assert_allclose(extra[:, 0], 3 / 10)  # three gates left of three
    core = base.core
    np.testing.assert_allclose(extra[:, 1], core.params.mass / core.cfg.quad.mass - 1, atol=1e-6)
    assert np.ptp(extra[:, 1]) > 0  # randomised masses differ
    gate_side = core.g_size[:, 0] - 1
    np.testing.assert_allclose(extra[:, 8], gate_side, atol=1e-6)
    # after a step the gates left and the terminal observations keep their shape
    o2, _, done, infos = env.step(np.zeros((6, 4), np.float32))
    assert o2.shape == obs.shape
    for i in np.flatnonzero(done):
        assert infos[i]["terminal_observation"].shape == (obs.shape[1],)


def test_the_actor_never_reads_the_privileged_block_and_the_critic_does():
    env = make_train_env(TINY, 4, 3, seed=0)
    model = PPO(
        AsymmetricActorCriticPolicy, env, n_steps=8, batch_size=32, device="cpu", seed=0,
        policy_kwargs={"net_arch": [16, 16], "actor_dim": env.actor_dim},
    )  # fmt: skip
    obs = torch.as_tensor(env.reset())
    other = obs.clone()
    other[:, env.actor_dim :] += 1.0
    pol = model.policy
    with torch.no_grad():
        a1, a2 = (
            pol.get_distribution(obs).distribution.mean,
            pol.get_distribution(other).distribution.mean,
        )
        v1, v2 = pol.predict_values(obs), pol.predict_values(other)
    torch.testing.assert_close(a1, a2)
    assert not torch.allclose(v1, v2)
    assert pol.mlp_extractor.policy_net[0].in_features == env.actor_dim


def test_a_run_with_the_privileged_critic_exports_an_ordinary_policy_and_resumes(tmp_path):
    out = tmp_path / "run"
    result = train_policy(TINY, out, seed=0, timesteps=512)
    policy = load_policy(result.policy_path)
    assert policy.obs_dim == 21  # the extended observation: nothing of the critic's
    model = PPO.load(out / "checkpoints" / "last.zip", device="cpu")
    env = make_train_env(replace(TINY, perception=PerceptionNoiseConfig(enabled=False)), 4, 3, 1)
    obs = env.reset()
    raw = env.base.core.observe(env.base.state)
    # the exported actor's action is the model's deterministic action on the same features
    np.testing.assert_allclose(
        policy.act(raw), np.clip(model.predict(obs, deterministic=True)[0], -1, 1), atol=1e-5
    )
    again = train_policy(TINY, out, seed=0, timesteps=1024, resume=True)
    assert again.timesteps == 1024


def test_the_privileged_critic_is_off_unless_the_config_asks(tmp_path):
    assert RACING.privileged_critic is False
    path = tmp_path / "c.toml"
    path.write_text('preset = "racing"\nprivileged_critic = true\n')
    assert load_train_config(path).privileged_critic is True
    path.write_text('preset = "racing"\nprivileged_critic = "yes"\n')
    with pytest.raises(ValueError, match="privileged_critic"):
        load_train_config(path)
