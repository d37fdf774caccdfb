"""Physics backends by name, and the Gymnasium registration ``gym.make("IcarusRace-v0", backend=...)``.

Built in: ``batched`` (numpy), ``pybullet`` and ``mujoco``. A third party adds a backend without
editing the package, in one of two ways:

* an entry point in its own package's metadata, group ``icarus_vision.backends``::

      [project.entry-points."icarus_vision.backends"]
      my-sim = "my_package.backend:MySimDroneRacingEnv"

* or, from Python, ``register_backend("my-sim", MySimDroneRacingEnv)``.

Either way ``make_env("my-sim", ...)``, ``race --backend my-sim`` and ``eval-policy --backend
my-sim`` find it. A backend is a ``DroneRacingEnv`` subclass (or a callable returning one) that
implements ``_backend_reset`` and ``_backend_step``; docs/simulation.md shows a minimal one.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from importlib.metadata import entry_points

import gymnasium as gym

ENV_ID = "IcarusRace-v0"
ENTRY_POINT_GROUP = "icarus_vision.backends"
BUILTIN = {
    "batched": "icarus_vision.sim.env:BatchedDroneRacingEnv",
    "pybullet": "icarus_vision.sim.pybullet_backend:PyBulletDroneRacingEnv",
    "mujoco": "icarus_vision.sim.mujoco_backend:MuJoCoDroneRacingEnv",
}
BACKENDS = tuple(BUILTIN)
"""The built-in backends (``backend_names()`` adds the registered and installed ones)."""

_registered: dict[str, Callable] = {}


def register_backend(name: str, factory: Callable | str, *, overwrite: bool = False) -> None:
    """Make a backend available by name.

    Args:
        name: what ``--backend`` and ``make_env`` take.
        factory: a ``DroneRacingEnv`` subclass, a callable returning one from the env's keyword
            arguments, or its ``"module:attribute"`` path (imported on first use).
        overwrite: replace a backend already registered under ``name`` (built-ins never).
    """
    if not name or not isinstance(name, str):
        raise ValueError(f"a backend name must be a non-empty string, got {name!r}")
    if name in BUILTIN:
        raise ValueError(f"{name!r} is a built-in backend and cannot be replaced")
    if name in _registered and not overwrite:
        raise ValueError(f"backend {name!r} is already registered (overwrite=True replaces it)")
    _registered[name] = factory


def _installed() -> dict[str, object]:
    return {ep.name: ep for ep in entry_points(group=ENTRY_POINT_GROUP)}


def backend_names() -> tuple[str, ...]:
    """Every backend ``make_env`` can build: built-in, registered, then installed plug-ins."""
    names = list(BUILTIN) + [n for n in _registered if n not in BUILTIN]
    names += [n for n in _installed() if n not in names]
    return tuple(names)


def _load(path: str) -> Callable:
    module, _, attr = path.partition(":")
    return getattr(importlib.import_module(module), attr)


def resolve_backend(name: str) -> Callable:
    """The factory of a backend name (``ValueError`` naming the known ones if there is none)."""
    if name in BUILTIN:
        return _load(BUILTIN[name])
    if name in _registered:
        factory = _registered[name]
        return _load(factory) if isinstance(factory, str) else factory
    check_backend(name)  # what is left is an installed plug-in, or nothing
    installed = _installed()
    try:
        return installed[name].load()
    except Exception as e:  # a broken plug-in names itself rather than failing obscurely
        raise ValueError(
            f"backend {name!r} (entry point {installed[name].value}) failed to load: {e}"
        ) from e


def check_backend(name: str) -> str:
    """``name`` if a backend of that name exists (without importing it), else ``ValueError``."""
    if name not in backend_names():
        raise ValueError(f"unknown backend {name!r}; choose one of {', '.join(backend_names())}")
    return name


def make_env(backend: str = "batched", **kwargs):
    """Create a DroneRacingEnv with the named backend; kwargs are EnvConfig fields or ``config``."""
    from icarus_vision.sim.env import DroneRacingEnv

    env = resolve_backend(backend)(**kwargs)
    if not isinstance(env, DroneRacingEnv):
        raise TypeError(
            f"backend {backend!r} built a {type(env).__name__}, not a DroneRacingEnv subclass"
        )
    return env


def register() -> None:
    if ENV_ID not in gym.registry:
        gym.register(ENV_ID, entry_point="icarus_vision.sim.registration:make_env")
