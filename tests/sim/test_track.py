from __future__ import annotations

import math

import numpy as np
import pytest

from icarus_vision.sim.builtin import BUILTIN_TRACKS, DEFAULT_TRACK, builtin_track, resolve_track
from icarus_vision.sim.random_track import random_track
from icarus_vision.sim.track import Gate, Track, TrackError, load_track, save_track

FULL = """
name = "example"
laps = 2
[start]
pos = [0.0, 0.0, 0.2]
yaw_deg = 10.0
[defaults]
size = 1.5
frame_width = 0.2
[bounds]
min = [-10.0, -10.0, 0.0]
max = [30.0, 10.0, 8.0]
[[gates]]
pos = [5.0, 0.0, 2.0]
yaw_deg = 0.0
[[gates]]
pos = [10.0, 0.0, 2.0]
yaw_deg = 180.0
size = 1.0
[[gates]]
pos = [5.0, 0.0, 2.0]
yaw_deg = 180.0
"""


def write(tmp_path, text, name="t.toml"):
    p = tmp_path / name
    p.write_text(text)
    return p


def test_load_full_format(tmp_path):
    t = load_track(write(tmp_path, FULL))
    assert t.name == "example" and t.laps == 2 and t.start_yaw_deg == 10.0
    assert t.gates[0].size == 1.5 and t.gates[0].frame_width == 0.2  # from [defaults]
    assert t.gates[1].size == 1.0  # per-gate override
    assert t.bounds_min == (-10.0, -10.0, 0.0) and t.bounds_max == (30.0, 10.0, 8.0)
    assert t.num_passages == 6 and len(t.passages) == 6
    # gate 0 and gate 2 share a position: one physical gate flown both ways
    assert len(t.physical_gates()) == 2


def test_save_load_round_trip(tmp_path):
    t = load_track(write(tmp_path, FULL))
    save_track(t, tmp_path / "out.toml")
    assert load_track(tmp_path / "out.toml") == t


def test_default_bounds_margin():
    t = Track("t", (Gate((5.0, 0.0, 2.0)),), (0.0, 0.0, 0.2))
    assert t.bounds_min == (-5.0, -5.0, 0.0)
    assert t.bounds_max == (10.0, 5.0, 7.0)


def test_corner_order_tl_tr_br_bl():
    c = Gate((5.0, 0.0, 2.0), 0.0, 1.0).corners()
    np.testing.assert_allclose(c, [[5, 0.5, 2.5], [5, -0.5, 2.5], [5, -0.5, 1.5], [5, 0.5, 1.5]])
    # a gate passed along +y: its left is -x
    c = Gate((0.0, 0.0, 2.0), 90.0, 1.0).corners()
    np.testing.assert_allclose(c[0], [-0.5, 0.0, 2.5], atol=1e-12)


@pytest.mark.parametrize(
    "text, match",
    [
        ("[start]\npos=[0,0,0.2]\n[[gates]]\npos=[5,0,2]\n", "missing required key 'name'"),
        (
            'name="x"\n[start]\npos=[0,0,0.2]\n[[gates]]\nyaw_deg=0.0\n',
            "gate 0: missing required key 'pos'",
        ),
        (
            'name="x"\n[start]\npos=[0,0,0.2]\n[[gates]]\npos=[5,0,2]\ncolour=1\n',
            "gate 0: unknown key",
        ),
        ('name="x"\nspeed=1\n[start]\npos=[0,0,0.2]\n[[gates]]\npos=[5,0,2]\n', "unknown key"),
        (
            'name="x"\n[start]\npos=[0,0,0.2]\n[[gates]]\npos=[5,0,2]\n[[gates]]\npos=[9,0,nan]\n',
            "gate 1: pos must be a finite",
        ),
        (
            'name="x"\n[start]\npos=[0,0,0.2]\n[[gates]]\npos=[5,0,2]\nyaw_deg=inf\n',
            "gate 0: yaw_deg must be a finite",
        ),
        (
            'name="x"\n[start]\npos=[0,0,0.2]\n[[gates]]\npos=[5,0,2]\nsize=0.0\n',
            "gate 0: size must be > 0",
        ),
        (
            'name="x"\n[start]\npos=[0,0,0.2]\n[[gates]]\npos=[5,0,2]\nsize=-1.0\n',
            "gate 0: size must be > 0",
        ),
        (
            'name="x"\n[start]\npos=[5,0.55,2]\n[[gates]]\npos=[5,0,2]\n',
            "gate 0: the start position",
        ),
        ('name="x"\n[start]\npos=[0,0]\n[[gates]]\npos=[5,0,2]\n', "start.pos must be a list of 3"),
        ('name="x"\n[start]\npos=[0,0,0.2]\n', "at least one gate"),
        ('name="x"\nlaps=0\n[start]\npos=[0,0,0.2]\n[[gates]]\npos=[5,0,2]\n', "laps must be"),
        ("name = = 1", "not a valid TOML"),
    ],
)
def test_malformed_files_are_refused_naming_file_and_gate(tmp_path, text, match):
    path = write(tmp_path, text, "bad.toml")
    with pytest.raises(TrackError, match=match) as e:
        load_track(path)
    assert "bad.toml" in str(e.value)


def test_missing_file(tmp_path):
    with pytest.raises(TrackError, match="not found"):
        load_track(tmp_path / "nope.toml")


def test_builtin_tracks():
    assert DEFAULT_TRACK in BUILTIN_TRACKS
    sg = builtin_track("single-gate")
    assert len(sg.gates) == 1 and sg.gates[0].pos == (5.0, 0.0, 2.0) and sg.gates[0].size == 1.0
    assert np.linalg.norm(sg.start_pos[:2]) < 0.5
    for name, n in (("three-gates", 3), ("five-gates", 5), ("ten-gates", 10)):
        t = builtin_track(name)
        assert len(t.gates) == n
        z = [g.pos[2] for g in t.gates]
        yaws = [g.yaw_deg for g in t.gates]
        assert max(z) - min(z) >= 0.5, "height changes"
        assert max(yaws) - min(yaws) >= 30, "turns"
    assert resolve_track(None).name == DEFAULT_TRACK
    with pytest.raises(TrackError, match="built-in tracks: single-gate"):
        resolve_track("no-such-track")


def test_random_track_is_seeded_and_within_documented_ranges():
    a, b = random_track(10, 7), random_track(10, 7)
    assert a == b
    assert random_track(10, 8) != a
    for seed in range(30):
        t = random_track(10, seed)
        pos = np.array([g.pos for g in t.gates])
        steps = np.linalg.norm(np.diff(pos[:, :2], axis=0), axis=1)
        assert np.all(steps >= 4.0 - 1e-9) and np.all(steps <= 8.0 + 1e-9)
        assert np.all((pos[:, 2] >= 1.0) & (pos[:, 2] <= 3.0))
        assert np.all(np.abs(np.diff(pos[:, 2])) <= 1.0 + 1e-9)
        d = np.linalg.norm(pos[:, None, :2] - pos[None, :, :2], axis=2) + np.eye(10) * 99
        assert d.min() >= 3.0
        yaw = np.radians([g.yaw_deg for g in t.gates])
        turn = np.angle(np.exp(1j * np.diff(yaw)))
        assert np.all(np.abs(turn) <= math.radians(60 + 2 * 15) + 1e-9)
