"""Short real training runs: learning signal, export fidelity, checkpoints and resume."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest
from stable_baselines3 import PPO

from icarus_vision.policy.config import FAST, CurriculumConfig, PPOConfig
from icarus_vision.policy.export import load_policy
from icarus_vision.policy.features import obs_to_features
from icarus_vision.policy.train import train_policy
from icarus_vision.sim.config import EnvConfig
from icarus_vision.sim.vec_env import BatchedRacingVecEnv

TINY = replace(
    FAST,
    ppo=PPOConfig(num_envs=64, n_steps=64, batch_size=1024, n_epochs=8, learning_rate=1e-3),
    curriculum=CurriculumConfig(stages=(1, 3)),
    checkpoint_every=8192,
    eval_every=16384,
    eval_episodes=16,
)


def mean_return(act, episodes: int = 64, seed: int = 123) -> float:
    env = BatchedRacingVecEnv(episodes, EnvConfig(random_tracks=True, num_gates=1))
    env.seed(seed)
    obs = env.reset()
    returns: list[float | None] = [None] * episodes
    while any(r is None for r in returns):
        obs, _, done, infos = env.step(act(obs))
        for i in np.flatnonzero(done):
            if returns[i] is None:
                returns[i] = infos[i]["episode"]["r"]
    return float(np.mean(returns))


@pytest.mark.slow
def test_short_training_beats_random_and_exports_faithfully(tmp_path):
    res = train_policy(TINY, tmp_path / "run", seed=0, timesteps=200_000, verbose=0)
    assert res.timesteps >= 200_000
    pol = load_policy(res.policy_path)
    rng = np.random.default_rng(0)
    trained = mean_return(pol.act)
    random = mean_return(lambda o: rng.uniform(-1, 1, (len(o), 4)))
    assert trained > random + 20, (trained, random)
    # the exported numpy policy gives the SB3 model's deterministic actions
    model = PPO.load(tmp_path / "run" / "checkpoints" / "last.zip", device="cpu")
    obs = BatchedRacingVecEnv(32, EnvConfig(random_tracks=True, num_gates=3)).reset()
    sb3, _ = model.predict(obs_to_features(obs), deterministic=True)
    np.testing.assert_allclose(pol.act(obs), sb3, atol=1e-5)
    for name in ("config.json", "metrics.json", "best.safetensors", "best.json"):
        assert (tmp_path / "run" / name).is_file()
    assert list((tmp_path / "run" / "tb").glob("**/events.out.tfevents.*"))


def test_resume_continues_step_count_and_stage(tmp_path):
    out = tmp_path / "run"
    first = train_policy(TINY, out, seed=1, timesteps=8192, verbose=0)
    state = json.loads((out / "checkpoints" / "last_state.json").read_text())
    assert state["timesteps"] == first.timesteps == 8192
    with pytest.raises(ValueError, match="--resume"):
        train_policy(TINY, out, seed=1, timesteps=8192, verbose=0)
    second = train_policy(TINY, out, seed=1, resume=True, timesteps=16384, verbose=0)
    assert second.timesteps == 16384
    assert json.loads((out / "checkpoints" / "last_state.json").read_text())["timesteps"] == 16384


def test_resume_errors_leave_files_untouched(tmp_path):
    with pytest.raises(FileNotFoundError, match="no checkpoint"):
        train_policy(TINY, tmp_path / "none", resume=True, timesteps=10, verbose=0)
    out = tmp_path / "run"
    (out / "checkpoints").mkdir(parents=True)
    (out / "checkpoints" / "last.zip").write_bytes(b"not a zip")
    (out / "checkpoints" / "last_state.json").write_text(
        '{"stage": 0, "best": [-1, -1], "wall_s": 0, "metrics": []}'
    )
    with pytest.raises(ValueError, match="corrupt checkpoint"):
        train_policy(TINY, out, resume=True, timesteps=10, verbose=0)
    assert (out / "checkpoints" / "last.zip").read_bytes() == b"not a zip"


def test_ctrl_c_saves_a_resumable_checkpoint(tmp_path):
    out = tmp_path / "run"

    def interrupt(ts, curriculum):
        if ts >= 5000:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        train_policy(TINY, out, seed=2, timesteps=100_000, progress=interrupt, verbose=0)
    state = json.loads((out / "checkpoints" / "last_state.json").read_text())
    assert 5000 <= state["timesteps"] < 100_000
    res = train_policy(
        TINY, out, seed=2, resume=True, timesteps=state["timesteps"] + 4096, verbose=0
    )
    assert res.timesteps >= state["timesteps"] + 4096


def test_cli_train_policy_stops_at_max_minutes(tmp_path):
    from typer.testing import CliRunner

    from icarus_vision.cli import app

    cfg = tmp_path / "tiny.toml"
    cfg.write_text(
        'preset = "fast"\ncheckpoint_every = 1000000000\neval_every = 1000000000\n'
        "[ppo]\nnum_envs = 16\nn_steps = 32\nbatch_size = 256\nn_epochs = 2\ntorch_threads = 1\n"
    )
    out = tmp_path / "run"
    res = CliRunner().invoke(
        app,
        [
            "train-policy",
            "--config",
            str(cfg),
            "--timesteps",
            "1000000000",
            "--max-minutes",
            "0.03",
            "--out",
            str(out),
        ],
    )
    assert res.exit_code == 0, res.output
    state = json.loads((out / "checkpoints" / "last_state.json").read_text())
    assert 0 < state["timesteps"] < 1_000_000 and 1.5 <= state["wall_s"] < 30
    assert (out / "policy.safetensors").is_file()


def test_resume_refuses_another_config_and_bad_state(tmp_path):
    out = tmp_path / "run"
    train_policy(TINY, out, seed=1, timesteps=4096, verbose=0)
    other = replace(TINY, ppo=replace(TINY.ppo, learning_rate=5e-4))
    before = (out / "config.json").read_text()
    with pytest.raises(ValueError, match=r"another config \(differs in ppo.learning_rate\)"):
        train_policy(other, out, seed=1, resume=True, timesteps=8192, verbose=0)
    assert (out / "config.json").read_text() == before  # nothing overwritten
    state_path = out / "checkpoints" / "last_state.json"
    for bad in ("{}", '{"stage": 7, "best": [0, 0.5]}', "[]"):
        state_path.write_text(bad)
        with pytest.raises(ValueError, match="checkpoint state|out of range"):
            train_policy(TINY, out, seed=1, resume=True, timesteps=8192, verbose=0)


def test_cli_resume_uses_the_runs_own_config(tmp_path):
    from typer.testing import CliRunner

    from icarus_vision.cli import app

    cfg = tmp_path / "tiny.toml"
    cfg.write_text(
        "total_timesteps = 4096\ncheckpoint_every = 4096\neval_every = 100000\n"
        "[ppo]\nnum_envs = 32\nn_steps = 64\nbatch_size = 1024\nn_epochs = 2\n"
        "[curriculum]\nstages = [1]\n"
    )
    out = tmp_path / "run"
    runner = CliRunner()
    res = runner.invoke(app, ["train-policy", "--config", str(cfg), "--out", str(out)])
    assert res.exit_code == 0, res.output
    res = runner.invoke(app, ["train-policy", "--resume", "--out", str(out), "--timesteps", "6144"])
    assert res.exit_code == 0, res.output  # no --config: the run's own
    res = runner.invoke(app, ["train-policy", "--resume", "--out", str(out), "--preset", "classic"])
    assert res.exit_code == 1 and "another config" in res.output


@pytest.mark.parametrize(
    "table, match",
    [
        ({"randomization": {"mass_pct": 5}}, "mass_pct"),
        ({"randomization": {"drag_pct": 1.0}}, "drag_pct"),
        ({"randomization": {"wind_mps": -1.0}}, "wind_mps"),
        ({"perception": {"sigma_base_m": -0.1}}, "sigma_base_m"),
        ({"perception": {"miss_base": 3}}, "miss_base"),
        ({"total_timesteps": 1.5}, "total_timesteps: must be an integer"),
        ({"max_episode_s": -2.0}, "max_episode_s"),
        ({"ppo": {"learning_rate": "fast"}}, "learning_rate: must be a finite number"),
        ({"ppo": {"net_arch": [64, "x"]}}, "net_arch"),
        ({"curriculum": {"stages": 5}}, "stages"),
        ({"reward": 3}, "reward: must be a non-empty string"),
        ({"ppo": {"learning_rate_final": -1e-4}}, "learning_rate_final"),
        ({"ppo": {"log_std_final": 5.0}}, "log_std_final"),
    ],
)
def test_config_values_of_the_wrong_type_or_range_are_refused(table, match):
    from icarus_vision.policy.config import config_from_dict

    with pytest.raises(ValueError, match=match):
        config_from_dict(table, "x.toml")


def test_every_evaluated_policy_is_exported_with_its_evaluation(tmp_path):
    out = tmp_path / "run"
    train_policy(replace(TINY, eval_every=4096, eval_episodes=4), out, seed=2, timesteps=8192,
                 verbose=0)  # fmt: skip
    evaluated = sorted((out / "evaluated").glob("*.json"))
    assert [p.stem for p in evaluated] == ["000004096", "000008192"]
    metas = [json.loads(p.read_text())["meta"] for p in evaluated]
    assert [m["timesteps"] for m in metas] == [4096, 8192]
    assert all(0.0 <= m["eval_success"] <= 1.0 for m in metas)
    best = json.loads((out / "best.json").read_text())["meta"]
    assert best["name"] == "best" and best["timesteps"] in (4096, 8192)
    chosen = out / "evaluated" / f"{best['timesteps']:09d}.safetensors"
    assert chosen.read_bytes() == (out / "best.safetensors").read_bytes()
    assert load_policy(chosen).obs_dim == load_policy(out / "best").obs_dim


def test_the_schedules_lower_the_learning_rate_and_the_log_std_and_survive_a_resume(tmp_path):
    from stable_baselines3.common.callbacks import BaseCallback

    ppo = replace(TINY.ppo, learning_rate=1e-3, learning_rate_final=1e-4, log_std_init=0.0,
                  log_std_final=-2.0)  # fmt: skip
    cfg = replace(TINY, ppo=ppo)
    out = tmp_path / "run"
    seen = []  # (learning rate, largest log std) as each rollout begins

    class Seen(BaseCallback):
        def _on_rollout_start(self) -> None:
            seen.append((self.model.lr_schedule(1.0), self.model.policy.log_std.max().item()))

        def _on_step(self) -> bool:
            return True

    train_policy(cfg, out, seed=0, timesteps=8192, verbose=0, callbacks=lambda c, e: [Seen()])
    assert seen[0] == (pytest.approx(1e-3), pytest.approx(0.0))
    assert seen[1][0] == pytest.approx(1e-3 + 0.5 * (1e-4 - 1e-3))  # 4096 of 8192 steps done
    assert seen[1][1] <= -1.0 + 1e-6
    state = json.loads((out / "checkpoints" / "last_state.json").read_text())
    assert state["log_std_start"] == [0.0] * 4  # where each axis started
    model = PPO.load(out / "checkpoints" / "last.zip", device="cpu")
    assert model.policy.log_std.max().item() <= -2.0 + 1e-6  # the run's end: the final ceiling
    # resumed for twice the steps: halfway as it goes on, three quarters at its next rollout
    seen.clear()
    train_policy(cfg, out, seed=0, resume=True, timesteps=16384, verbose=0,
                 callbacks=lambda c, e: [Seen()])  # fmt: skip
    assert [lr for lr, _ in seen] == pytest.approx([5.5e-4, 3.25e-4])
    state = json.loads((out / "checkpoints" / "last_state.json").read_text())
    assert state["log_std_start"] == [0.0] * 4  # kept, not taken again from the resumed model
    model = PPO.load(out / "checkpoints" / "last.zip", device="cpu")
    assert model.policy.log_std.max().item() <= -2.0 + 1e-6


def test_without_schedules_the_learning_rate_stays_and_nothing_is_recorded(tmp_path):
    out = tmp_path / "run"
    train_policy(TINY, out, seed=0, timesteps=8192, verbose=0)
    assert "log_std_start" not in json.loads((out / "checkpoints" / "last_state.json").read_text())
    model = PPO.load(out / "checkpoints" / "last.zip", device="cpu")
    assert model.policy.optimizer.param_groups[0]["lr"] == pytest.approx(1e-3)
