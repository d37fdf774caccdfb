"""Shared fixtures: every physics backend, for contract tests over each; Ray, started once."""

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


@pytest.fixture(scope="session")
def ray_here():
    """Ray started once per test session on this machine (sweep and gen-dataset --ray reuse a
    running Ray instead of starting their own)."""
    import ray

    from icarus_vision.ray_runtime import start_ray

    start_ray(num_cpus=2)
    yield
    ray.shutdown()
