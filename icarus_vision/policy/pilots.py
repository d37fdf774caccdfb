"""Resolve a policy name or path to a pilot: the shipped default, an exported file, or 'scripted'."""

from __future__ import annotations

from importlib import resources
from pathlib import Path

from icarus_vision.policy.export import ExportedPolicy, load_policy


def default_policy_path() -> Path:
    """The shipped default policy (``icarus_vision/models/policy/default.safetensors``)."""
    return Path(str(resources.files("icarus_vision").joinpath("models/policy/default.safetensors")))


def resolve_policy(spec: str | None, expect_obs_dim: int | None = None) -> ExportedPolicy | str:
    """'default' / None -> the shipped policy; 'scripted' -> the scripted controller; else a path."""
    if spec == "scripted":
        return "scripted"
    path = default_policy_path() if spec in (None, "default") else Path(spec)
    return load_policy(path, expect_obs_dim)
