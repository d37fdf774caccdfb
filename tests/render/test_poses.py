"""Racing-like poses: ranges, no-gate frames really show no gate, determinism."""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from icarus_vision.render.camera import Camera
from icarus_vision.render.labels import frame_labels
from icarus_vision.render.poses import gates_in_view, sample_poses, sample_track
from icarus_vision.render.recipe import PoseRanges, TrackRanges, load_recipe
from icarus_vision.render.scene import Scene
from icarus_vision.sim.dynamics import quat_to_rpy

RECIPE = Path(__file__).resolve().parents[2] / "datasets" / "gates-v1.toml"


@pytest.fixture(scope="module")
def track():
    return sample_track(TrackRanges(gates=(6, 6)), np.random.default_rng(5))


def test_tracks_follow_the_ranges():
    rng = np.random.default_rng(0)
    ranges = TrackRanges(gates=(3, 5), size=(0.8, 1.4))
    for _ in range(10):
        t = sample_track(ranges, rng)
        assert 3 <= len(t.gates) <= 5
        assert all(0.8 <= g.size <= 1.4 and 1.0 <= g.pos[2] <= 3.0 for g in t.gates)


def test_approach_poses_are_racing_like(track):
    ranges = PoseRanges(no_gate_prob=0.0)
    cam = Camera()
    poses = sample_poses(ranges, np.random.default_rng(1), track, cam, 2000)
    rpy = np.degrees(quat_to_rpy(poses.quat))
    assert np.all(np.abs(rpy[:, :2]) <= 45.0 + 1e-9)
    assert np.abs(rpy[:, 0]).max() > 40 and np.abs(rpy[:, 1]).max() > 40  # the full range is used
    assert np.all((poses.pos[:, 2] >= 0.3) & (poses.pos[:, 2] <= 6.0))
    gpos = np.array([g.pos for g in track.gates])[poses.target]
    normal = np.array([g.normal for g in track.gates])[poses.target]
    d = np.linalg.norm(poses.pos - gpos, axis=1)
    assert d.min() < 1.0 and d.max() > 12.0 and np.all(d < 17.0)  # 0.5-15 m plus offsets
    assert np.mean(np.einsum("ij,ij->i", poses.pos - gpos, normal) < 0) > 0.97  # approach side
    # Aimed at the target: it is in front of the camera and mostly in the image, sometimes not.
    r_wc = np.stack([cam.pose(p, q)[0] for p, q in zip(poses.pos, poses.quat, strict=True)])
    z = np.einsum("ij,ijk->ik", gpos - poses.pos, r_wc)[:, 2]
    assert np.mean(z > 0) > 0.95
    frames = zip(gpos, poses.pos, poses.quat, strict=True)
    in_image = [bool(cam.in_image(cam.project(g, p, q)[0])) for g, p, q in frames]
    assert 0.6 < np.mean(in_image) < 0.99


def test_share_of_no_gate_frames(track):
    poses = sample_poses(
        PoseRanges(no_gate_prob=0.25), np.random.default_rng(2), track, Camera(), 800
    )
    share = np.mean(poses.target < 0)
    assert abs(share - 0.25) < 0.05
    empty = poses.target < 0
    assert not gates_in_view(track, Camera(), poses.pos[empty], poses.quat[empty]).any()


def test_no_gate_frames_render_no_gate_and_gate_frames_show_gates(track):
    recipe = load_recipe(RECIPE)
    ranges = replace(recipe.poses, no_gate_prob=0.5)
    cam = Camera(width=160, height=120)
    poses = sample_poses(ranges, np.random.default_rng(3), track, cam, 24)
    labelled = []
    with Scene(track, cam) as scene:
        for pos, quat, target in zip(poses.pos, poses.quat, poses.target, strict=True):
            frame = scene.render(pos, quat)
            if target < 0:
                assert not np.isin(frame.seg, scene.gate_bodies).any()
            else:
                labelled.append(len(frame_labels(scene, frame, pos, quat)))
    assert np.mean(np.array(labelled) > 0) > 0.8 and max(labelled) >= 2  # several gates in view


def test_gates_in_view_is_conservative(track):
    """Whenever a gate shows in a render, the frustum test said it might."""
    rng = np.random.default_rng(4)
    cam = Camera(width=80, height=60)
    lo, hi = np.asarray(track.bounds_min), np.asarray(track.bounds_max)
    pos = rng.uniform(lo, hi, (40, 3))
    pos[:, 2] = rng.uniform(0.3, 5.0, 40)
    yaw = rng.uniform(-math.pi, math.pi, 40)
    quat = np.stack([np.zeros(40), np.zeros(40), np.sin(yaw / 2), np.cos(yaw / 2)], axis=1)
    said = gates_in_view(track, cam, pos, quat)
    with Scene(track, cam) as scene:
        seen = [
            np.isin(scene.render(p, q).seg, scene.gate_bodies).any()
            for p, q in zip(pos, quat, strict=True)
        ]
    assert np.all(said[np.array(seen)])
    assert 0 < np.sum(seen) < 40


def test_same_rng_same_poses(track):
    a = sample_poses(PoseRanges(), np.random.default_rng(9), track, Camera(), 50)
    b = sample_poses(PoseRanges(), np.random.default_rng(9), track, Camera(), 50)
    assert np.array_equal(a.pos, b.pos) and np.array_equal(a.quat, b.quat)
    assert np.array_equal(a.target, b.target)
