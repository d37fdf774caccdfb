from __future__ import annotations

import pytest

from icarus_vision.policy.config import CLASSIC, FAST, PRESETS, load_train_config


def test_classic_preset_is_the_classic_setup():
    p = CLASSIC.ppo
    assert p.num_envs * p.n_steps == 2048 and p.batch_size == 64 and p.n_epochs == 10
    assert (p.learning_rate, p.gamma, p.gae_lambda, p.clip_range, p.ent_coef) == (
        3e-4,
        0.99,
        0.95,
        0.2,
        0.01,
    )
    assert set(PRESETS) == {"classic", "fast", "racing", "specialist"} and FAST.ppo.num_envs >= 64


def test_load_config_overrides_preset(tmp_path):
    p = tmp_path / "c.toml"
    p.write_text(
        'preset = "classic"\ntotal_timesteps = 1000\nreward = "racing"\n[ppo]\nlearning_rate = 0.001\nnet_arch = [32, 32]\n'
    )
    c = load_train_config(p)
    assert c.preset == "classic" and c.total_timesteps == 1000 and c.ppo.learning_rate == 1e-3
    assert c.ppo.net_arch == (32, 32) and c.ppo.n_epochs == 10
    assert c.reward_config().speed > 0 and c.reward_config().time < 0


@pytest.mark.parametrize(
    "text, match",
    [
        ("speed = 3\n", "unknown key.*speed"),
        ("[ppo]\nlr = 0.1\n", r"\[ppo\]: lr: unknown key"),
        ("[ppo]\nlearning_rate = -1.0\n", "ppo.learning_rate is out of range"),
        ("[ppo]\nbatch_size = 100000000\n", "ppo.batch_size is out of range"),
        ('reward = "fastest"\n', "reward is out of range"),
        ('preset = "turbo"\n', "unknown preset"),
        ("[curriculum]\npromote_success = 1.5\n", "curriculum.promote_success"),
        ("total_timesteps = = 3", "not a valid TOML"),
    ],
)
def test_bad_config_names_the_key(tmp_path, text, match):
    p = tmp_path / "bad.toml"
    p.write_text(text)
    with pytest.raises(ValueError, match=match):
        load_train_config(p)
