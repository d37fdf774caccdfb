"""Gymnasium registration: ``gym.make("IcarusRace-v0", track=..., backend="batched"|"pybullet")``."""

from __future__ import annotations

import gymnasium as gym

ENV_ID = "IcarusRace-v0"
BACKENDS = ("batched", "pybullet")


def make_env(backend: str = "batched", **kwargs):
    """Create a DroneRacingEnv with the named backend; kwargs are EnvConfig fields or ``config``."""
    if backend == "batched":
        from icarus_vision.sim.env import BatchedDroneRacingEnv

        return BatchedDroneRacingEnv(**kwargs)
    if backend == "pybullet":
        from icarus_vision.sim.pybullet_backend import PyBulletDroneRacingEnv

        return PyBulletDroneRacingEnv(**kwargs)
    raise ValueError(f"unknown backend {backend!r}; choose one of {', '.join(BACKENDS)}")


def register() -> None:
    if ENV_ID not in gym.registry:
        gym.register(ENV_ID, entry_point="icarus_vision.sim.registration:make_env")
