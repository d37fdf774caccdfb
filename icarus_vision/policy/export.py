"""Exported policies: an MLP in safetensors plus a JSON description, loaded without pickles.

Format ``icarus-policy-v1`` (two files side by side, ``NAME.safetensors`` and ``NAME.json``):
the JSON names the observation (``basic`` 15-D, ``extended`` 21-D or ``racing`` 25-D, gate
vectors in the world frame), the feature transform version, the hidden layers and activation, and the action semantics
(``ctbr``: [thrust, roll_rate, pitch_rate, yaw_rate] in [-1, 1]). Inference is plain numpy:
features -> tanh MLP -> mean action, clipped to [-1, 1] (the deterministic policy). A specialist
trained with its track's plan features (``"reference": "plan"``) carries the plan in its tensors
(``ref.*``: ``policy/reference.py``) and appends its features to the transform's.
"""

from __future__ import annotations

import json
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from safetensors.numpy import load as load_safetensors
from safetensors.numpy import save as save_safetensors

from icarus_vision.fileio import atomic_write_bytes, atomic_write_json
from icarus_vision.policy.features import (
    FEATURES_V1,
    FEATURES_V2,
    FEATURES_VERSION,
    FEATURES_VERSIONS,
    feature_dim,
    policy_input,
)
from icarus_vision.policy.reference import PlanReference
from icarus_vision.sim.observation import OBS_DIMS
from icarus_vision.sim.quad import QuadParams

FORMAT = "icarus-policy-v1"
ACTION = "ctbr"


def _paths(path: str | Path) -> tuple[Path, Path]:
    p = Path(path)
    stem = p.with_suffix("") if p.suffix in (".safetensors", ".json") else p
    return stem.with_suffix(".safetensors"), stem.with_suffix(".json")


def _write(path: str | Path, tensors: dict, desc: dict) -> Path:
    """Write a policy's tensors and description atomically; returns the .safetensors path."""
    st, js = _paths(path)
    atomic_write_bytes(st, save_safetensors(tensors))
    atomic_write_json(js, desc)
    return st


def export_sb3_policy(
    model,
    path: str | Path,
    observation: str,
    meta: dict | None = None,
    features: str = FEATURES_VERSION,
    reference: PlanReference | None = None,
) -> Path:
    """Write a stable-baselines3 PPO MlpPolicy's actor as ``path``.safetensors + ``path``.json;
    ``features`` names the feature transform it was trained on, ``reference`` the plan whose
    features it reads after them (None: none).

    Returns:
        The .safetensors path.
    """
    pol = model.policy
    layers = [m for m in pol.mlp_extractor.policy_net if hasattr(m, "weight")]
    tensors = {}
    for i, layer in enumerate([*layers, pol.action_net]):
        tensors[f"w{i}"] = layer.weight.detach().cpu().numpy().astype(np.float32)
        tensors[f"b{i}"] = layer.bias.detach().cpu().numpy().astype(np.float32)
    act = (
        type(pol.mlp_extractor.policy_net[1]).__name__.lower()
        if len(pol.mlp_extractor.policy_net) > 1
        else "tanh"
    )
    desc = {
        "format": FORMAT,
        "observation": observation,
        "obs_dim": OBS_DIMS[observation],
        "gate_frame": "world",
        "features": features,
        "hidden": [int(layer.out_features) for layer in layers],
        "activation": act,
        "action": ACTION,
        "action_dim": 4,
        "meta": meta or {},
    }
    if reference is not None:
        desc["reference"] = "plan"
        tensors |= reference.tensors()
    return _write(path, tensors, desc)


@dataclass
class ExportedPolicy:
    """A loaded exported policy. ``act(obs)`` maps (N, obs_dim) or (obs_dim,) to actions."""

    weights: list[tuple[np.ndarray, np.ndarray]]
    desc: dict
    path: Path
    reference: PlanReference | None = None
    """The track's plan whose features the policy reads after the transform's (specialists
    trained with ``reference = "plan"``), or None."""

    @property
    def obs_dim(self) -> int:
        return int(self.desc["obs_dim"])

    @property
    def observation(self) -> str:
        return self.desc["observation"]

    @property
    def features(self) -> str:
        """The feature transform the policy reads (``features.FEATURES_V1`` or ``_V2``)."""
        return self.desc["features"]

    @property
    def name(self) -> str:
        return self.desc.get("meta", {}).get("name", self.path.stem)

    @property
    def quad(self) -> str:
        """Name of the quadrotor it was trained for (a policy that records none, like those
        exported before quadrotor files could be trained for, was trained for the built-in one)."""
        return self.desc.get("meta", {}).get("quad", QuadParams().name)

    def check_quad(self, quad: QuadParams, flight: str = "this race") -> None:
        """Warn when ``quad`` is not the quadrotor the policy was trained for."""
        if self.quad != quad.name:
            warnings.warn(
                f"policy {self.name} was trained for the quadrotor {self.quad!r}; {flight} "
                f"flies {quad.name!r}",
                stacklevel=3,
            )

    def check_track(self, track, flight: str = "this race") -> None:
        """Warn when the policy reads a plan (``reference``) of another track than ``track``
        (None: random tracks): a gate of ``track`` more than 1 m from every planned one."""
        if self.reference is None:
            return
        if track is None or np.any(
            self.reference.gate_distance(np.array([g.pos for g in track.gates])) > 1.0
        ):
            warnings.warn(
                f"policy {self.name} reads the plan of the track it was trained on; {flight} "
                "flies another track, where that plan does not lead through the gates",
                stacklevel=3,
            )

    def act(self, obs: np.ndarray) -> np.ndarray:
        """Deterministic actions.

        Args:
            obs: (N, obs_dim) or (obs_dim,) observations, gate vectors in the world frame.

        Returns:
            (N, 4) or (4,) float32 actions in [-1, 1].
        """
        obs = np.asarray(obs, dtype=np.float32)
        single = obs.ndim == 1
        x = obs[None] if single else obs
        if x.ndim != 2 or x.shape[1] != self.obs_dim:
            raise ValueError(
                f"policy {self.path} expects observations of {self.obs_dim} entries, got shape {obs.shape}"
            )
        h = policy_input(x, self.features, self.reference)
        for w, b in self.weights[:-1]:
            h = np.tanh(h @ w.T + b)
        w, b = self.weights[-1]
        out = np.clip(h @ w.T + b, -1.0, 1.0).astype(np.float32)
        return out[0] if single else out


def load_policy(path: str | Path, expect_obs_dim: int | None = None) -> ExportedPolicy:
    """Load an exported policy; errors name the file and any convention that does not match.

    Raises:
        FileNotFoundError: a file is missing.
        ValueError: corrupt file, unknown format, or observation/action conventions that differ
            from what the caller flies (``expect_obs_dim``; actions must be 4-D CTBR).
    """
    st, js = _paths(path)
    for f in (st, js):
        if not f.is_file():
            raise FileNotFoundError(f"{f}: policy file not found")
    try:
        desc = json.loads(js.read_text())
        tensors = load_safetensors(st.read_bytes())
    except Exception as e:  # noqa: BLE001 - any decoding failure is a corrupt file
        raise ValueError(f"{st}: corrupt or unreadable policy ({type(e).__name__}: {e})") from None
    if not isinstance(desc, dict):
        raise ValueError(f"{js}: a policy description must be a JSON object")
    if desc.get("format") != FORMAT:
        raise ValueError(f"{js}: unknown policy format {desc.get('format')!r} (expected {FORMAT})")
    if desc.get("action") != ACTION or desc.get("action_dim") != 4:
        raise ValueError(
            f"{js}: action convention {desc.get('action')!r}/{desc.get('action_dim')} does not match ctbr/4"
        )
    if desc.get("features") not in FEATURES_VERSIONS.values() or desc.get("gate_frame") != "world":
        raise ValueError(
            f"{js}: feature transform {desc.get('features')!r} (gate frame {desc.get('gate_frame')!r}) does not match {FEATURES_V1} or {FEATURES_V2} (world)"
        )
    if desc.get("obs_dim") not in OBS_DIMS.values():
        raise ValueError(
            f"{js}: observation of {desc.get('obs_dim')} entries does not match the 15-D, 21-D or 25-D observations this simulator provides"
        )
    if OBS_DIMS.get(desc.get("observation")) != desc["obs_dim"]:
        raise ValueError(
            f"{js}: observation {desc.get('observation')!r} does not have {desc['obs_dim']} entries ({', '.join(f'{k} {v}' for k, v in OBS_DIMS.items())})"
        )
    if expect_obs_dim is not None and desc.get("obs_dim") != expect_obs_dim:
        raise ValueError(
            f"{js}: policy observes {desc.get('obs_dim')} entries but this run provides {expect_obs_dim}"
        )
    hidden = desc.get("hidden")
    if not isinstance(hidden, list) or not all(
        isinstance(h, int) and not isinstance(h, bool) and h > 0 for h in hidden
    ):
        raise ValueError(f"{js}: hidden must be a list of layer widths, got {hidden!r}")
    reference = None
    if desc.get("reference") is not None:
        if desc["reference"] != "plan":
            raise ValueError(f"{js}: unknown reference {desc['reference']!r} (expected 'plan')")
        try:
            reference = PlanReference.from_tensors(tensors)
        except ValueError as e:
            raise ValueError(f"{st}: {e}") from None
        if desc["obs_dim"] < OBS_DIMS["extended"]:
            raise ValueError(f"{js}: plan features need the extended or racing observation")
    n = len(hidden) + 1
    try:
        weights = [(tensors[f"w{i}"], tensors[f"b{i}"]) for i in range(n)]
    except KeyError as e:
        raise ValueError(f"{st}: missing tensor {e}") from None
    if (
        weights[0][0].shape[1]
        != feature_dim(desc["obs_dim"], desc["features"]) + (reference.dim if reference else 0)
        or weights[-1][0].shape[0] != 4
    ):
        raise ValueError(f"{st}: layer shapes do not match the description in {js.name}")
    return ExportedPolicy(weights, desc, st, reference)


def average_policies(paths: list[str | Path], out: str | Path, meta: dict | None = None) -> Path:
    """Write the mean of exported policies' weights as ``out`` (stochastic weight averaging).

    Policies taken from one training run's plateau (``OUT/evaluated/``) share their start, so
    their average is a policy too, and often a steadier one than any of them.

    Args:
        paths: exported policies of one observation, feature transform and architecture.
        out: the averaged policy's path (``.safetensors`` and ``.json`` beside each other).
        meta: the averaged policy's meta (its ``averaged`` entry lists ``paths``).

    Raises:
        ValueError: no policy, or policies that differ in what they read, their layers or the
            quadrotor they were trained for.
    """
    if not paths:
        raise ValueError("average of no policies: give at least one")
    policies = [load_policy(p) for p in paths]
    keys = ("observation", "obs_dim", "features", "hidden", "activation", "reference")
    first = policies[0]
    for pol in policies[1:]:
        differ = [k for k in keys if pol.desc.get(k) != first.desc.get(k)]
        differ += ["quadrotor"] if pol.quad != first.quad else []
        if differ:
            raise ValueError(
                f"{pol.path}: its {', '.join(differ)} differ from {first.path}'s; only policies "
                "of one observation, feature transform and architecture are averaged"
            )
    tensors = {}
    for i in range(len(first.weights)):
        for j, name in enumerate(("w", "b")):
            stack = np.stack([pol.weights[i][j] for pol in policies]).astype(np.float32)
            tensors[f"{name}{i}"] = stack.mean(axis=0, dtype=np.float32)
    if first.reference is not None:  # one run's policies fly one track's plan
        tensors |= first.reference.tensors()
    desc = {k: v for k, v in first.desc.items() if k != "meta"}
    desc["meta"] = {**(meta or {}), "averaged": [str(pol.path.with_suffix("")) for pol in policies],
                    "quad": first.quad}  # fmt: skip
    return _write(out, tensors, desc)


def load_init_actor(
    model, spec: str, observation: str, features: str = FEATURES_VERSION, reference: bool = False
) -> ExportedPolicy:
    """Copy an exported policy's actor into a fresh stable-baselines3 PPO model (fine-tuning).

    A policy of a smaller observation than the run's (``basic`` into ``extended`` or ``racing``,
    ``extended`` into ``racing``) starts with zero first-layer weights for the features it did not
    read, so it flies as before until training finds a use for them (the features of a smaller
    observation are the first ones of a larger: ``features.py``). Likewise a run with wider hidden
    layers (same depth) keeps the new units' fresh input weights and gives their outputs zero
    weight, so the wider actor computes exactly the exported one's actions and training grows the
    new units from there. A version 1 policy starts a version 2 run the same way (version 2
    appends its features after version 1's); a version 2 policy continues only with version 2
    features of its own observation. A run with plan features (``reference``) starts from a
    policy without them the same way (they come last); a policy with them continues only a run
    with them, of its own observation and transform.

    Args:
        model: PPO with an MlpPolicy whose actor has the exported policy's hidden layers.
        spec: ``default`` (the shipped generalist), a shipped name, or a path to an exported policy.
        observation: the run's observation (``basic``, ``extended`` or ``racing``).
        features: the run's feature transform.
        reference: whether the run reads plan features after the transform's.

    Raises:
        ValueError: the policy reads a larger observation than the run's, features the run's
            transform does not start with, or its layers differ from the model's.
    """
    import torch

    from icarus_vision.policy.pilots import resolve_policy

    policy = resolve_policy(spec)
    if not isinstance(policy, ExportedPolicy):
        raise ValueError(f"cannot start training from {spec!r}: it is not an exported policy")
    if policy.obs_dim > OBS_DIMS[observation]:
        raise ValueError(
            f"{policy.path}: it reads the {policy.observation} observation ({policy.obs_dim} entries), "
            f"larger than this run's {observation} ({OBS_DIMS[observation]}); set observation = "
            f"{policy.observation!r} in the config"
        )
    # Version 2 appends its gate-frame features after the layout's version 1 ones, so a
    # version 2 policy's features begin no other layout's or version's.
    if policy.features == FEATURES_V2 and (
        features != FEATURES_V2 or policy.obs_dim != OBS_DIMS[observation]
    ):
        raise ValueError(
            f"{policy.path}: it reads features {policy.features} of the {policy.observation} "
            f"observation, which this run's ({features}, {observation}) do not start with; set "
            f"features = 'v2' and observation = {policy.observation!r} in the config"
        )
    if policy.reference is not None and (
        not reference or policy.obs_dim != OBS_DIMS[observation] or policy.features != features
    ):
        raise ValueError(
            f"{policy.path}: it reads plan features after those of {policy.features} on the "
            f"{policy.observation} observation; continue it with reference = 'plan', "
            f"features = {policy.features!r} and observation = {policy.observation!r}"
        )
    weights = list(policy.weights)
    pol = model.policy
    layers = [m for m in pol.mlp_extractor.policy_net if hasattr(m, "weight")]
    layers.append(pol.action_net)
    if len(layers) != len(weights) or any(
        layer.weight.shape[0] < w.shape[0] for layer, (w, _) in zip(layers, weights, strict=True)
    ):
        raise ValueError(
            f"{policy.path}: its layers {policy.desc['hidden']} do not match this run's ppo.net_arch "
            "(the run's layers must be as many and at least as wide)"
        )
    with torch.no_grad():
        for layer, (w, b) in zip(layers, weights, strict=True):
            out_old, in_old = w.shape
            new_w = layer.weight.detach().numpy().copy()
            # The exported units ignore the features and the new units it did not have.
            new_w[:out_old, :in_old] = w
            new_w[:out_old, in_old:] = 0.0
            new_b = layer.bias.detach().numpy().copy()
            new_b[:out_old] = b
            layer.weight.copy_(torch.from_numpy(new_w))
            layer.bias.copy_(torch.from_numpy(new_b))
    return policy
