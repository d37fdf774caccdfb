"""The search-space file of ``icarus-vision sweep``: which ``train-policy`` settings to vary, and how.

A TOML file with four tables (only ``[search]`` is required)::

    [base]                  # the train-policy config every trial starts from (its keys as in
    preset = "fast"         # a --config file); default: the fast preset
    observation = "extended"

    [search]                # dotted train-policy keys -> one distribution each
    "ppo.learning_rate" = { loguniform = [1e-4, 3e-3] }
    "ppo.ent_coef" = { uniform = [0.0, 0.01] }
    "ppo.n_epochs" = { int = [3, 10] }                 # both ends included
    "ppo.net_arch" = { choice = [[64, 64], [128, 128]] }

    [objective]             # what a trial is worth (evaluated on random tracks, deterministic)
    metric = "success"      # success (tie-break: curriculum stage) or speed (success − 0.1 s⁻¹ ×
    gates = 10              #   median lap per gate)
    episodes = 128
    difficulty = 1.0        # race-layout difficulty; leave out for the classic layouts

    [[start]]               # optional points evaluated first, e.g. today's config
    "ppo.learning_rate" = 1e-3

Every error names the file and the key, in one line.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, fields, is_dataclass
from pathlib import Path

from icarus_vision.fileio import read_toml
from icarus_vision.policy.config import TrainConfig, config_from_dict, config_to_dict

DISTRIBUTIONS = ("uniform", "loguniform", "int", "choice")
METRICS = ("success", "speed")


@dataclass(frozen=True)
class Distribution:
    """One searched setting: ``kind`` in DISTRIBUTIONS; ``values`` (low, high) or the choices."""

    kind: str
    values: tuple

    def corners(self) -> list:
        """Values that bound the distribution (checked against the config at load time)."""
        return list(self.values)


@dataclass(frozen=True)
class Objective:
    """How a trial is scored (``metric``) and on what (random tracks of ``gates`` gates)."""

    metric: str = "success"
    gates: int = 10
    episodes: int = 128
    difficulty: float | None = None


@dataclass(frozen=True)
class SearchSpace:
    """A parsed search-space file."""

    source: str
    base: dict
    search: dict[str, Distribution]
    objective: Objective
    start: tuple[dict, ...] = ()

    def trial_config(self, params: dict) -> TrainConfig:
        """The TrainConfig of one trial: ``base`` with ``params`` (dotted keys) set."""
        return config_from_dict(with_params(self.base, params), f"{self.source} (trial)")


def config_keys() -> list[str]:
    """Every dotted TrainConfig key a search may vary."""
    keys = []
    for f in fields(TrainConfig):
        default = getattr(TrainConfig(), f.name)
        if is_dataclass(default):
            keys += [f"{f.name}.{g.name}" for g in fields(default)]
        elif f.name != "preset":
            keys.append(f.name)
    return keys


def with_params(base: dict, params: dict) -> dict:
    """A copy of the config table ``base`` with dotted ``params`` set in it."""
    out = json.loads(json.dumps(base))
    for key, value in params.items():
        table, _, name = key.rpartition(".")
        (out.setdefault(table, {}) if table else out)[name] = value
    return out


def _number(v) -> bool:
    return isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v)


def _distribution(key: str, spec, where: str) -> Distribution:
    if not isinstance(spec, dict) or len(spec) != 1:
        raise ValueError(
            f"{where}: must be one distribution, e.g. {{ uniform = [0.0, 1.0] }} "
            f"({', '.join(DISTRIBUTIONS)})"
        )
    ((kind, values),) = spec.items()
    if kind not in DISTRIBUTIONS:
        raise ValueError(f"{where}: unknown distribution {kind!r}; use {', '.join(DISTRIBUTIONS)}")
    if not isinstance(values, list) or not values:
        raise ValueError(f"{where}: {kind} needs a list of values")
    if kind == "choice":
        return Distribution(kind, tuple(values))
    if len(values) != 2 or not all(_number(v) for v in values) or values[0] >= values[1]:
        raise ValueError(f"{where}: {kind} needs [low, high] with finite low < high")
    if kind == "loguniform" and values[0] <= 0:
        raise ValueError(f"{where}: loguniform needs low > 0")
    if kind == "int" and not all(isinstance(v, int) for v in values):
        raise ValueError(f"{where}: int needs integer bounds")
    return Distribution(kind, tuple(values))


def _suggest(key: str, known: list[str]) -> str:
    import difflib

    close = difflib.get_close_matches(key, known, n=3)
    return f" (did you mean {', '.join(close)}?)" if close else ""


def load_space(path: str | Path) -> SearchSpace:
    """Read and check a search-space file (unknown keys, bad distributions, out-of-range bounds)."""
    src = str(path)
    data = read_toml(path, "search space", FileNotFoundError)
    unknown = set(data) - {"base", "search", "objective", "start"}
    if unknown:
        raise ValueError(
            f"{src}: unknown table {sorted(unknown)[0]!r}; use base, search, objective, start"
        )
    base = data.get("base", {})
    if not isinstance(base, dict):
        raise ValueError(f"{src}: [base] must be a table of train-policy settings")
    config_from_dict(base, f"{src} [base]")  # the base alone must be a valid config
    search_table = data.get("search")
    if not isinstance(search_table, dict) or not search_table:
        raise ValueError(f"{src}: [search] must name at least one setting to vary")
    known = config_keys()
    search = {}
    for key, spec in search_table.items():
        if key not in known:
            raise ValueError(
                f"{src}: search.{key}: not a train-policy setting{_suggest(key, known)}"
            )
        search[key] = dist = _distribution(key, spec, f"{src}: search.{key}")
        for v in dist.corners():  # each bound and choice must make a valid config
            try:
                config_from_dict(with_params(base, {key: v}), "")
            except ValueError as e:
                msg = str(e).removeprefix(": ")
                raise ValueError(
                    f"{src}: search.{key}: the value {v!r} is refused ({msg})"
                ) from None
    obj = data.get("objective", {})
    if not isinstance(obj, dict):
        raise ValueError(f"{src}: [objective] must be a table")
    bad = set(obj) - {f.name for f in fields(Objective)}
    if bad:
        raise ValueError(
            f"{src}: objective.{sorted(bad)[0]}: unknown; use metric, gates, episodes, difficulty"
        )
    objective = Objective(**obj)
    if objective.metric not in METRICS:
        raise ValueError(f"{src}: objective.metric must be one of {', '.join(METRICS)}")
    if not (isinstance(objective.gates, int) and objective.gates >= 1):
        raise ValueError(f"{src}: objective.gates must be an integer >= 1")
    if not (isinstance(objective.episodes, int) and objective.episodes >= 1):
        raise ValueError(f"{src}: objective.episodes must be an integer >= 1")
    if objective.difficulty is not None and not (
        _number(objective.difficulty) and 0 <= objective.difficulty <= 1
    ):
        raise ValueError(f"{src}: objective.difficulty must be in [0, 1]")
    start = data.get("start", [])
    if not isinstance(start, list) or not all(isinstance(s, dict) for s in start):
        raise ValueError(f"{src}: [[start]] entries must be tables of searched settings")
    for i, point in enumerate(start):
        extra = set(point) - set(search)
        if extra:
            raise ValueError(f"{src}: start[{i}].{sorted(extra)[0]}: not a searched setting")
    return SearchSpace(src, base, search, objective, tuple(start))


def encode_choice(value) -> str:
    """A choice as Optuna can hold it (numbers, strings, lists: all as their JSON text)."""
    return json.dumps(value)


def to_tune(space: SearchSpace) -> dict:
    """The Ray Tune search space (choices travel as JSON text; ``decode`` turns them back)."""
    from ray import tune

    out = {}
    for key, d in space.search.items():
        lo_hi = d.values
        if d.kind == "uniform":
            out[key] = tune.uniform(*lo_hi)
        elif d.kind == "loguniform":
            out[key] = tune.loguniform(*lo_hi)
        elif d.kind == "int":
            out[key] = tune.randint(lo_hi[0], lo_hi[1] + 1)  # randint's high is exclusive
        else:
            out[key] = tune.choice([encode_choice(v) for v in d.values])
    return out


def encode_point(space: SearchSpace, point: dict) -> dict:
    """A ``[[start]]`` point in the form ``to_tune``'s space samples."""
    return {
        k: encode_choice(v) if space.search[k].kind == "choice" else v for k, v in point.items()
    }


def decode(space: SearchSpace, params: dict) -> dict:
    """Sampled parameters as train-policy values (choices from their JSON text, ints as int)."""
    out = {}
    for key, v in params.items():
        d = space.search.get(key)
        if d is None:
            continue
        if d.kind == "choice":
            out[key] = json.loads(v)
        elif d.kind == "int":
            out[key] = int(v)
        else:
            out[key] = float(v)
    return out


def best_config_dict(space: SearchSpace, params: dict) -> dict:
    """The full train-policy config (as a TOML table) of a trial's parameters."""
    cfg = space.trial_config(params)
    d = config_to_dict(cfg)
    return _drop_none(d)


def _drop_none(d: dict) -> dict:
    """TOML has no null: leave unset (None) settings out (they take their defaults when read)."""
    out = {}
    for k, v in d.items():
        if isinstance(v, dict):
            out[k] = _drop_none(v)
        elif v is not None:
            out[k] = v
    return out
