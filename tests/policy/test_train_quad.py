"""Training, evaluating and racing a policy for a quadrotor file other than the built-in one."""

from __future__ import annotations

import json
import shutil
import warnings
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from icarus_vision.cli import app
from icarus_vision.policy.config import FAST, RACING, CurriculumConfig, PPOConfig
from icarus_vision.policy.evaluate import evaluate_policy
from icarus_vision.policy.export import load_policy
from icarus_vision.policy.pilots import shipped_policy_path
from icarus_vision.policy.train import make_train_env, train_policy
from icarus_vision.racing.runner import run_race
from icarus_vision.sim.config import RandomizationConfig
from icarus_vision.sim.quad import QuadError, QuadParams, load_quad


def quad_file(tmp_path: Path, name: str, uptilt: float = 20.0, ttw: float = 4.0) -> Path:
    path = tmp_path / f"{name}.toml"
    path.write_text(f'name = "{name}"\nthrust_to_weight = {ttw}\n[camera]\nuptilt_deg = {uptilt}\n')
    return path


def perception_cost_at_start(cfg) -> float:
    """The camera-angle cost of the first step, hovering at single-gate's start."""
    env = make_train_env(cfg, 1, 1, seed=0)
    env.reset()
    base = env.unwrapped
    env.step(np.array([[base.config.quad.hover_thrust_action, 0.0, 0.0, 0.0]]))
    return float(base.last_reward_terms["perception"][0])


def test_the_camera_angle_cost_reads_the_config_quads_camera(tmp_path):
    # single-gate's gate is 20° above the start's horizon: on the axis of a 20° camera, 40° off a
    # 60° one (10° outside the cost's 30° cone)
    cfg = replace(
        RACING, track="single-gate", init=None, perception_cost=1.0,
        randomization=RandomizationConfig(enabled=False),
    )  # fmt: skip
    level = perception_cost_at_start(replace(cfg, quad=str(quad_file(tmp_path, "a", 20.0))))
    steep = perception_cost_at_start(replace(cfg, quad=str(quad_file(tmp_path, "b", 60.0))))
    assert level == 0.0
    assert steep == pytest.approx(-np.radians(10.0), abs=0.02)
    # the out-of-view rule sees through the same camera
    env = make_train_env(replace(cfg, quad=str(quad_file(tmp_path, "c", 60.0))), 2, 1, seed=0)
    assert env.venv.noise.camera.uptilt_deg == 60.0


def test_a_policy_trained_for_a_quad_records_it_and_starts_at_its_hover(tmp_path):
    tiny = replace(
        FAST,
        ppo=PPOConfig(num_envs=16, n_steps=32, batch_size=256, n_epochs=1, torch_threads=1),
        curriculum=CurriculumConfig(stages=(1,)),
        checkpoint_every=10**9,
        eval_every=512,
        eval_episodes=4,
        quad=str(quad_file(tmp_path, "heavy", ttw=2.5)),
    )
    res = train_policy(tiny, tmp_path / "run", seed=0, timesteps=512, verbose=0)
    pol = load_policy(res.policy_path)
    assert pol.quad == "heavy"
    assert [load_policy(p).quad for p in (tmp_path / "run" / "evaluated").glob("*.json")] == [
        "heavy"
    ]
    # one short update moves the bias little from the heavy drone's hover (2/2.5 - 1 = -0.2),
    # far from the built-in drone's (2/4 - 1 = -0.5)
    assert abs(pol.weights[-1][1][0] - (-0.2)) < 0.1
    assert json.loads((tmp_path / "run" / "config.json").read_text())["quad"] == tiny.quad


def test_a_missing_quad_file_fails_before_anything_is_written(tmp_path):
    cfg = replace(FAST, quad=str(tmp_path / "nope.toml"))
    with pytest.raises(QuadError, match="nope.toml"):
        train_policy(cfg, tmp_path / "run", timesteps=64, verbose=0)
    assert not (tmp_path / "run").exists()
    res = CliRunner().invoke(
        app, ["train-policy", "--quad", str(tmp_path / "nope.toml"), "--out", str(tmp_path / "r")]
    )
    assert res.exit_code != 0 and "nope.toml" in res.output
    assert not (tmp_path / "r").exists()


def test_eval_policy_flies_the_quad_file(tmp_path):
    # a drone that cannot lift itself (thrust-to-weight 1.05 with the policy's hover command of a
    # 4:1 drone) finishes nothing that the built-in drone finishes
    weak = quad_file(tmp_path, "weak", ttw=1.05)
    args = ["eval-policy", "--policy", "default", "--track", "single-gate", "--episodes", "4"]
    built_in = CliRunner().invoke(app, [*args, "--json", str(tmp_path / "a.json")])
    assert built_in.exit_code == 0, built_in.output
    res = CliRunner().invoke(app, [*args, "--quad", str(weak), "--json", str(tmp_path / "b.json")])
    assert res.exit_code == 0, res.output
    assert json.loads((tmp_path / "a.json").read_text())["success_rate"] == 1.0
    assert json.loads((tmp_path / "b.json").read_text())["success_rate"] == 0.0
    bad = CliRunner().invoke(app, [*args, "--quad", str(tmp_path / "nope.toml")])
    assert bad.exit_code != 0 and "nope.toml" in bad.output


def test_race_warns_when_the_policy_was_trained_for_another_quad(tmp_path):
    src = shipped_policy_path("default")
    for ext in (".json", ".safetensors"):
        shutil.copyfile(src.with_suffix(ext), tmp_path / f"pol{ext}")
    desc = json.loads((tmp_path / "pol.json").read_text())
    desc["meta"]["quad"] = "other-drone"
    (tmp_path / "pol.json").write_text(json.dumps(desc))
    race = dict(detector="oracle", policy=str(tmp_path / "pol"), backend="batched")
    with pytest.warns(UserWarning, match="trained for the quadrotor 'other-drone'"):
        run_race("single-gate", **race)
    desc["meta"]["quad"] = "racer-500g"
    (tmp_path / "pol.json").write_text(json.dumps(desc))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        run_race("single-gate", **race)
    # a policy that records none was trained for the built-in drone
    del desc["meta"]["quad"]
    (tmp_path / "pol.json").write_text(json.dumps(desc))
    with pytest.warns(
        UserWarning, match="trained for the quadrotor 'racer-500g'; this race flies 'mine'"
    ):
        run_race("single-gate", quad=load_quad(quad_file(tmp_path, "mine")), **race)


def test_eval_policy_warns_too():
    pol = load_policy(shipped_policy_path("default"))
    with pytest.warns(UserWarning, match="'racer-500g'; this evaluation flies 'mine'"):
        evaluate_policy(pol, "single-gate", episodes=1, quad=QuadParams(name="mine"))


def test_an_average_keeps_the_quad_and_refuses_policies_of_two(tmp_path):
    from icarus_vision.policy.export import average_policies

    src = shipped_policy_path("default")
    paths = []
    for name, quad in (("a", "mine"), ("b", "mine"), ("c", "another")):
        shutil.copyfile(src.with_suffix(".safetensors"), tmp_path / f"{name}.safetensors")
        desc = json.loads(src.with_suffix(".json").read_text())
        desc["meta"] = {"name": name, "quad": quad}
        (tmp_path / f"{name}.json").write_text(json.dumps(desc))
        paths.append(tmp_path / name)
    assert load_policy(average_policies(paths[:2], tmp_path / "avg")).quad == "mine"
    with pytest.raises(ValueError, match="quadrotor differ"):
        average_policies(paths, tmp_path / "bad")
