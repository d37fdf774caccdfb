"""Shared fixtures: both physics backends, for contract tests over every implementation."""

from __future__ import annotations

import pytest

from icarus_vision.sim.registration import BACKENDS, make_env


@pytest.fixture(params=BACKENDS)
def backend(request) -> str:
    return request.param


@pytest.fixture
def make(backend):
    """Factory for single-drone envs of the parametrised backend; closes them afterwards."""
    envs = []

    def _make(**kwargs):
        env = make_env(backend, **kwargs)
        envs.append(env)
        return env

    yield _make
    for env in envs:
        env.close()
