"""Resolve a policy name or path to a pilot: a shipped policy, an exported file, or 'scripted'.

Shipped policies live in ``icarus_vision/models/policy/``: ``default`` (the generalist, flown on
any track) and specialists named ``<track>-specialist``, each fine-tuned on one built-in track.
``auto`` picks the track's specialist when one is shipped for it, otherwise the generalist.
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path

from icarus_vision.policy.export import ExportedPolicy, load_policy
from icarus_vision.sim.builtin import BUILTIN_TRACKS, builtin_track
from icarus_vision.sim.track import Track

SPECIALIST_SUFFIX = "-specialist"


def _models_dir() -> Path:
    return Path(str(resources.files("icarus_vision").joinpath("models/policy")))


def default_policy_path() -> Path:
    """The shipped default policy (``icarus_vision/models/policy/default.safetensors``)."""
    return _models_dir() / "default.safetensors"


def shipped_policies() -> list[str]:
    """Names of the shipped policies: ``default`` and the ``<track>-specialist`` files."""
    return sorted(p.stem for p in _models_dir().glob("*.safetensors"))


def shipped_policy_path(name: str) -> Path | None:
    """The file of a shipped policy called ``name``; None if there is none."""
    return _models_dir() / f"{name}.safetensors" if name in shipped_policies() else None


def auto_policy_name(track: Track | None) -> str:
    """``<track>-specialist`` when ``track`` is a built-in track with a shipped specialist, else
    ``default``. The track must have the built-in layout (its gates and start), whatever its laps.
    """
    if track is None or track.name not in BUILTIN_TRACKS:
        return "default"
    name = track.name + SPECIALIST_SUFFIX
    if name not in shipped_policies():
        return "default"
    builtin = builtin_track(track.name)
    same = builtin.gates == track.gates and builtin.start_pos == track.start_pos
    return name if same else "default"


def resolve_policy(
    spec: str | None, expect_obs_dim: int | None = None, track: Track | None = None
) -> ExportedPolicy | str:
    """A pilot from a policy spec.

    Args:
        spec: ``auto`` (the track's specialist, else the generalist), ``default`` / None (the
            generalist), a shipped name (``grand-prix-specialist``), ``scripted``, or a path.
        track: the track to be flown (for ``auto``).
    """
    if spec == "scripted":
        return "scripted"
    if spec == "auto":
        spec = auto_policy_name(track)
    if spec is None:
        spec = "default"
    shipped = shipped_policy_path(spec)
    policy = load_policy(shipped if shipped is not None else Path(spec), expect_obs_dim)
    if shipped is not None:
        policy.desc.setdefault("meta", {})["name"] = spec
    return policy
