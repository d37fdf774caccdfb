"""race_track: documented ranges at every difficulty, the motifs, determinism, flyable episodes."""

from __future__ import annotations

import math

import numpy as np
import pytest

from icarus_vision.sim.config import EnvConfig
from icarus_vision.sim.race_layouts import (
    CLASSIC,
    FULL,
    MOTIFS,
    layout_ranges,
    race_track,
    track_motifs,
)
from icarus_vision.sim.random_track import random_track
from icarus_vision.sim.vec_env import BatchedRacingVecEnv


def _wrap(a: float) -> float:
    return (a + 180.0) % 360.0 - 180.0


def test_same_seed_same_track_and_other_seeds_differ():
    assert race_track(10, 5) == race_track(10, 5)
    assert race_track(10, 5) != race_track(10, 6)
    assert race_track(10, 5, difficulty=0.3) != race_track(10, 5)


def test_layout_ranges_interpolate_from_classic_to_full():
    assert layout_ranges(0.0) == CLASSIC
    assert layout_ranges(1.0) == FULL
    mid = layout_ranges(0.5)
    assert mid.spacing == pytest.approx((3.5, 11.5))
    assert mid.yaw_offset_deg == pytest.approx(37.5)
    with pytest.raises(ValueError, match="difficulty"):
        layout_ranges(1.5)


@pytest.mark.parametrize("difficulty", [0.0, 0.5, 1.0])
def test_every_gate_within_the_documented_ranges(difficulty):
    r = layout_ranges(difficulty)
    for seed in range(200):
        track = race_track(10, seed, difficulty=difficulty)
        assert track.num_passages == 10
        for g in track.gates:
            assert r.size[0] - 1e-9 <= g.size <= r.size[1] + 1e-9
            bottom = g.pos[2] - g.size / 2 - g.frame_width
            assert bottom >= 0.3 - 1e-9, "a gate's frame reaches the ground"
            assert g.pos[2] <= max(r.height[1], 3.0) + 1e-9
        physical = track.physical_gates()
        pos = np.array([g.pos for g in physical])
        gaps = np.linalg.norm(pos[:, None] - pos[None], axis=2) + np.eye(len(pos)) * 1e9
        stacked = np.linalg.norm(pos[:, None, :2] - pos[None, :, :2], axis=2) < 0.01
        assert gaps[~stacked].min() >= r.min_separation - 1e-9
        assert min(math.hypot(p[0], p[1]) for p in pos) >= 3.0 - 1e-9  # clear of the start


def test_single_gates_turn_and_face_within_range():
    """Gate-to-gate steps that are plain gates respect spacing, turn and yaw-offset limits."""
    r = FULL
    offsets = []
    for seed in range(300):
        track = race_track(10, seed)
        if track.laps > 1:
            continue
        g = track.gates
        for a, b in zip(g, g[1:], strict=False):
            d = np.subtract(b.pos, a.pos)
            if math.hypot(d[0], d[1]) < 0.01:  # hairpin or split-s
                continue
            approach = math.degrees(math.atan2(d[1], d[0]))
            offsets.append(abs(_wrap(b.yaw_deg - approach)))
            assert np.linalg.norm(d) <= math.hypot(r.spacing[1], r.max_climb) + 1e-6
    offsets = np.array(offsets)
    assert offsets.max() <= r.yaw_offset_deg + 1e-6
    assert np.mean(offsets > 30.0) > 0.2, "wide gate offsets are drawn"


def test_every_motif_appears_and_classic_difficulty_has_none():
    seen = set()
    for seed in range(300):
        seen |= track_motifs(race_track(10, seed))
    assert seen == set(MOTIFS)
    assert not any(track_motifs(race_track(10, s, difficulty=0.0)) for s in range(100))


def test_motif_geometry():
    for seed in range(300):
        track = race_track(10, seed)
        g = track.gates
        for a, b in zip(g, g[1:], strict=False):
            if math.hypot(a.pos[0] - b.pos[0], a.pos[1] - b.pos[1]) < 0.01:
                assert abs(abs(_wrap(a.yaw_deg - b.yaw_deg)) - 180.0) < 1e-6  # opposite ways
                if abs(a.pos[2] - b.pos[2]) > 0.01:  # split-s: the second is below the first
                    assert b.pos[2] < a.pos[2] - (a.size + b.size) / 2
        if track.laps > 1:
            assert track.laps == 2 and len(g) == 5 and track.num_passages == 10


def test_old_random_track_unchanged_under_its_seed():
    """The classic generator keeps its draws: the first gate of seed 3 as recorded before."""
    t = random_track(10, 3)
    assert t.name == "random-10-3"
    assert t == random_track(10, 3)
    assert all(1.0 <= g.pos[2] <= 3.0 for g in t.gates)


def test_env_draws_race_layouts_and_curriculum_hook_switches():
    env = BatchedRacingVecEnv(8, EnvConfig(random_tracks=True, num_gates=6, layout_difficulty=1.0))
    env.seed(0)
    env.reset()
    assert all(t.name.startswith("race-6") for t in env.core.tracks)
    env.set_difficulty(None)
    env.core.reset_drones(np.arange(8))
    assert all(t.name.startswith("random-6") for t in env.core.tracks)
    with pytest.raises(ValueError, match="difficulty"):
        env.set_difficulty(2.0)
    with pytest.raises(ValueError, match="layout_difficulty"):
        EnvConfig(random_tracks=True, layout_difficulty=-0.1)
