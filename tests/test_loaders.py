"""Property tests of every file loader: arbitrary TOML/JSON content gives a valid object or the
project's own error (a ValueError naming the file), never a TypeError, KeyError or the like."""

from __future__ import annotations

import json
import shutil

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from icarus_vision.policy.config import config_from_dict
from icarus_vision.policy.export import load_policy
from icarus_vision.policy.pilots import default_policy_path
from icarus_vision.sim.quad import QuadError, quad_from_dict
from icarus_vision.sim.track import TrackError, track_from_dict

SCALARS = st.one_of(
    st.integers(-5, 20), st.floats(allow_nan=True, allow_infinity=True), st.booleans(),
    st.text(max_size=4), st.none(),
)  # fmt: skip
VALUES = st.recursive(
    SCALARS,
    lambda inner: (
        st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=6), inner, max_size=4)
    ),
    max_leaves=12,
)


def tables(keys: list[str]):
    """Dicts over the loader's own keys (so the deep paths are reached) plus a stray one."""
    return st.dictionaries(st.sampled_from([*keys, "stray"]), VALUES, max_size=len(keys) + 1)


TRACK_KEYS = ["name", "laps", "start", "defaults", "bounds", "gates"]
GATE = st.fixed_dictionaries({"pos": VALUES}, optional={"yaw_deg": VALUES, "size": VALUES})
TRACK = st.fixed_dictionaries(
    {"name": VALUES, "start": st.one_of(VALUES, st.fixed_dictionaries({"pos": VALUES})),
     "gates": st.one_of(VALUES, st.lists(GATE, min_size=1, max_size=3))},
    optional={"laps": VALUES, "defaults": VALUES, "bounds": VALUES},
)  # fmt: skip
QUAD_KEYS = ["name", "mass", "inertia", "arm_length", "thrust_to_weight", "max_rate", "motor_tau",
             "drag", "radius", "camera"]  # fmt: skip
CONFIG_KEYS = ["preset", "total_timesteps", "ppo", "curriculum", "randomization", "perception",
               "reward", "observation", "max_episode_s", "track", "init", "time_cost",
               "perception_cost", "crash_cost", "center_reward", "align_reward"]  # fmt: skip


@settings(max_examples=300, deadline=None)
@given(st.one_of(TRACK, tables(TRACK_KEYS), VALUES))
def test_track_loader(data):
    try:
        track_from_dict(data, "t.toml")
    except TrackError as e:
        assert "t.toml" in str(e)


@settings(max_examples=300, deadline=None)
@given(st.one_of(tables(QUAD_KEYS), VALUES))
def test_quad_loader(data):
    try:
        quad_from_dict(data, "q.toml")
    except QuadError as e:
        assert "q.toml" in str(e)


@settings(max_examples=200, deadline=None)
@given(st.one_of(tables(CONFIG_KEYS), VALUES))
def test_train_config_loader(data):
    try:
        config_from_dict(data, "c.toml")
    except ValueError as e:
        assert "c.toml" in str(e) or "train config" in str(e)


@settings(
    max_examples=100, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(st.one_of(tables(["format", "observation", "obs_dim", "features", "hidden", "action",
                         "action_dim", "gate_frame"]), VALUES))  # fmt: skip
def test_policy_description_loader(tmp_path, desc):
    shutil.copy(default_policy_path(), tmp_path / "p.safetensors")
    (tmp_path / "p.json").write_text(json.dumps(desc))
    try:
        load_policy(tmp_path / "p.safetensors")
    except ValueError as e:
        assert "p.json" in str(e) or "p.safetensors" in str(e)
