"""Backends by name: built-ins, ``register_backend``, and a plug-in installed by entry point."""

from __future__ import annotations

import json
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env as gym_check_env
from typer.testing import CliRunner

import icarus_vision  # noqa: F401  (registers IcarusRace-v0)
from icarus_vision.cli import app
from icarus_vision.sim import registration
from icarus_vision.sim.env import BatchedDroneRacingEnv
from icarus_vision.sim.registration import (
    BACKENDS,
    backend_names,
    make_env,
    register_backend,
    resolve_backend,
)

PLUGIN_DIR = Path(__file__).parent / "plugin_backend"


@pytest.fixture
def installed_plugin(monkeypatch):
    """The test folder's tiny backend distribution on sys.path, as pip would leave it."""
    monkeypatch.syspath_prepend(str(PLUGIN_DIR))
    yield
    import sys

    sys.modules.pop("icarus_tiny_backend", None)


@pytest.fixture
def clean_registry(monkeypatch):
    monkeypatch.setattr(registration, "_registered", {})


def test_builtin_backends_are_listed_first():
    assert BACKENDS == ("batched", "pybullet", "mujoco")
    assert backend_names()[:3] == BACKENDS


def test_unknown_backend_names_the_known_ones():
    with pytest.raises(
        ValueError, match="unknown backend 'ode'; choose one of batched, pybullet, mujoco"
    ):
        make_env("ode")


def test_installed_plugin_is_found_by_name(installed_plugin):
    assert "tiny" in backend_names()
    env = gym.make("IcarusRace-v0", backend="tiny", track="three-gates").unwrapped
    assert env.backend_name == "tiny"
    gym_check_env(env)
    env.reset(seed=0)
    for _ in range(30):
        obs, *_ = env.step([0.0, 0.0, 0.0, 0.0])
    assert obs[2] > 0.5  # it flies: thrust above hover for 0.6 s


def test_installed_plugin_flies_eval_policy_from_the_cli(installed_plugin, tmp_path):
    res = CliRunner().invoke(app, ["eval-policy", "--policy", "scripted", "--track", "three-gates",
                                   "--episodes", "2", "--backend", "tiny",
                                   "--json", str(tmp_path / "e.json")])  # fmt: skip
    assert res.exit_code == 0, res.output
    report = json.loads((tmp_path / "e.json").read_text())
    assert report["backend"] == "tiny" and report["success_rate"] == 1.0


def test_broken_plugin_names_its_entry_point(installed_plugin):
    with pytest.raises(ValueError, match="icarus_tiny_backend:NoSuchClass"):
        resolve_backend("broken")


def test_register_backend_from_python(clean_registry):
    register_backend("numpy-again", BatchedDroneRacingEnv)
    assert "numpy-again" in backend_names()
    env = make_env("numpy-again", track="single-gate")
    obs, _ = env.reset(seed=0)
    assert np.all(np.isfinite(obs))
    register_backend("by-path", "icarus_vision.sim.env:BatchedDroneRacingEnv")
    assert isinstance(make_env("by-path"), BatchedDroneRacingEnv)
    with pytest.raises(ValueError, match="already registered"):
        register_backend("numpy-again", BatchedDroneRacingEnv)
    register_backend("numpy-again", BatchedDroneRacingEnv, overwrite=True)
    with pytest.raises(ValueError, match="built-in"):
        register_backend("mujoco", BatchedDroneRacingEnv)


def test_a_factory_that_builds_something_else_is_refused(clean_registry):
    register_backend("wrong", lambda **kw: object())
    with pytest.raises(TypeError, match="not a DroneRacingEnv"):
        make_env("wrong")
