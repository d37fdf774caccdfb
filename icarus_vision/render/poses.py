"""Racing-like camera poses around a track: the frames a racing drone sees, for dataset generation.

Most frames put the drone on its way to a gate of the track (the *target*), between ``distance``
metres away and the gate itself, in one of two ways:

* on the racing line: the straight line from the previous gate (or the start) to the target,
  offset sideways and vertically by a Gaussian, so earlier and later gates show up in view too;
* in the approach cone: anywhere on the target's approach side within an azimuth and elevation
  range of its passage axis.

The body is then turned so that the camera (with its uptilt) looks at the target, off by a random
aim offset of up to ``aim_offset_deg`` (which puts gates at or across the image border), rolled,
and its pitch clipped to the allowed range. A share ``no_gate_prob`` of the frames instead looks
away from every gate. All ranges come from :class:`icarus_vision.render.recipe.PoseRanges`.

Frames: world z up; body FLU; quaternions x, y, z, w (body -> world); ZYX roll, pitch, yaw with
positive pitch = nose down.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from icarus_vision.render.camera import Camera, camera_poses
from icarus_vision.render.frustum import spheres_in_view
from icarus_vision.render.recipe import PoseRanges, TrackRanges
from icarus_vision.sim.dynamics import rpy_to_quat
from icarus_vision.sim.random_track import random_track
from icarus_vision.sim.track import Track

GATE_MARGIN_M = 0.3
"""Bar width plus margin added to half a gate's opening for the no-gate visibility test, m."""


@dataclass(frozen=True)
class Poses:
    """N body poses.

    Attributes:
        pos: (N, 3) float64 body positions, world frame, m.
        quat: (N, 4) float64 body attitudes x, y, z, w (body -> world).
        target: (N,) int64 index in ``track.gates`` of the gate approached; -1 for no-gate frames.
    """

    pos: np.ndarray
    quat: np.ndarray
    target: np.ndarray

    def __len__(self) -> int:
        return len(self.target)


def _uniform(rng: np.random.Generator, r, n: int) -> np.ndarray:
    return rng.uniform(r[0], r[1], n) if r[1] > r[0] else np.full(n, float(r[0]))


def sample_track(ranges: TrackRanges, rng: np.random.Generator) -> Track:
    """A random track (the simulation core's generator) with layout parameters from ``ranges``."""
    n = int(rng.integers(ranges.gates[0], ranges.gates[1] + 1))
    size = float(_uniform(rng, ranges.size, 1)[0])
    return random_track(
        n,
        rng,
        spacing=ranges.spacing,
        max_turn_deg=ranges.max_turn_deg,
        height=ranges.height,
        size=size,
    )


def aim_attitudes(
    pos: np.ndarray,
    look_at: np.ndarray,
    offset: np.ndarray,
    offset_dir: np.ndarray,
    roll: np.ndarray,
    uptilt_deg: float,
    pitch_limits: tuple[float, float],
) -> np.ndarray:
    """Body attitudes that point a camera (pitched up by ``uptilt_deg``) near ``look_at``.

    Args:
        pos: (N, 3) body positions, world; look_at: (N, 3) world points to look at.
        offset: (N,) angle between the aimed direction and ``look_at``, rad.
        offset_dir: (N,) direction of that offset in the image plane, rad (0: to the left).
        roll: (N,) body roll, rad.
        uptilt_deg: camera uptilt, degrees.
        pitch_limits: (low, high) body pitch limits, degrees.

    Returns:
        (N, 4) quaternions x, y, z, w.
    """
    d = np.asarray(look_at, float) - np.asarray(pos, float)
    yaw = np.arctan2(d[:, 1], d[:, 0]) + offset * np.cos(offset_dir)
    elev = np.arctan2(d[:, 2], np.hypot(d[:, 0], d[:, 1])) + offset * np.sin(offset_dir)
    # The optical axis sits uptilt above body x: pitching the nose down by (uptilt - elev) aims it.
    pitch = np.clip(math.radians(uptilt_deg) - elev, *np.radians(pitch_limits))
    return rpy_to_quat(np.stack([roll, pitch, yaw], axis=-1))


def approach_poses(
    ranges: PoseRanges, rng: np.random.Generator, track: Track, camera: Camera, n: int
) -> Poses:
    """N poses approaching random gates of ``track`` (racing line or approach cone, see module)."""
    gates = track.gates
    target = rng.integers(len(gates), size=n)
    gpos = np.array([g.pos for g in gates], float)[target]
    prev = np.array([track.start_pos, *(g.pos for g in gates[:-1])], float)[target]
    yaw_g = np.array([g.yaw for g in gates])[target]
    dist = _uniform(rng, ranges.distance, n)
    on_line = rng.random(n) < ranges.racing_line_prob
    # Racing line: back from the target towards the previous gate, plus sideways / vertical offsets.
    u = gpos - prev
    u /= np.maximum(np.linalg.norm(u, axis=1, keepdims=True), 1e-9)
    side = np.stack([-u[:, 1], u[:, 0], np.zeros(n)], axis=1)
    side /= np.maximum(np.linalg.norm(side, axis=1, keepdims=True), 1e-9)
    up = np.cross(u, side)
    off = (
        rng.normal(0.0, ranges.lateral_std, (n, 2)) if ranges.lateral_std > 0 else np.zeros((n, 2))
    )
    line = gpos - dist[:, None] * u + off[:, :1] * side + off[:, 1:] * up
    # Approach cone: bearing from the gate within (azimuth, elevation) of its passage axis.
    az = yaw_g + np.radians(_uniform(rng, ranges.approach_azimuth_deg, n))
    el = np.radians(_uniform(rng, ranges.approach_elevation_deg, n))
    back = np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), -np.sin(el)], axis=1)
    cone = gpos - dist[:, None] * back
    pos = np.where(on_line[:, None], line, cone)
    pos[:, 2] = np.clip(pos[:, 2], *ranges.height)
    quat = aim_attitudes(
        pos,
        gpos,
        np.radians(_uniform(rng, ranges.aim_offset_deg, n)),
        rng.uniform(0.0, 2.0 * math.pi, n),
        np.radians(_uniform(rng, ranges.roll_deg, n)),
        camera.uptilt_deg,
        ranges.pitch_deg,
    )
    return Poses(pos, quat, target.astype(np.int64))


def gates_in_view(track: Track, camera: Camera, pos: np.ndarray, quat: np.ndarray) -> np.ndarray:
    """Conservative test: may any physical gate (front or back) show in the image?

    Each gate is bounded by a sphere (half its opening's diagonal plus :data:`GATE_MARGIN_M`).

    Args:
        pos: (N, 3) body positions; quat: (N, 4) attitudes x, y, z, w.

    Returns:
        (N,) bool, False only where no gate can be seen.
    """
    r_wc, t_wc = camera_poses(pos, quat, camera.r_body_cam)
    gates = track.physical_gates()
    centres = np.array([g.pos for g in gates], float)
    radius = np.array([(g.size / 2 + GATE_MARGIN_M) * math.sqrt(2.0) for g in gates])
    return spheres_in_view(camera, r_wc, t_wc, centres, radius).any(axis=1)


def no_gate_poses(
    ranges: PoseRanges,
    rng: np.random.Generator,
    track: Track,
    camera: Camera,
    n: int,
    max_rounds: int = 50,
) -> Poses:
    """N poses inside the track's bounds from which no gate can be seen (rejection sampling;
    after ``max_rounds`` batches the last candidates are kept whatever they show)."""
    lo, hi = np.asarray(track.bounds_min, float), np.asarray(track.bounds_max, float)
    pos_out, quat_out = np.zeros((0, 3)), np.zeros((0, 4))
    for rnd in range(max_rounds):
        m = max(4 * n, 8)
        pos = rng.uniform(lo, hi, (m, 3))
        pos[:, 2] = _uniform(rng, ranges.height, m)
        rpy = np.stack(
            [
                np.radians(_uniform(rng, ranges.roll_deg, m)),
                np.radians(_uniform(rng, ranges.pitch_deg, m)),
                rng.uniform(-math.pi, math.pi, m),
            ],
            axis=-1,
        )
        quat = rpy_to_quat(rpy)
        keep = ~gates_in_view(track, camera, pos, quat) if rnd < max_rounds - 1 else slice(None)
        pos_out = np.concatenate([pos_out, pos[keep]])
        quat_out = np.concatenate([quat_out, quat[keep]])
        if len(pos_out) >= n:
            break
    return Poses(pos_out[:n], quat_out[:n], np.full(n, -1, dtype=np.int64))


def sample_poses(
    ranges: PoseRanges, rng: np.random.Generator, track: Track, camera: Camera, n: int
) -> Poses:
    """N racing-like frames of ``track``: approach poses, of which a share ``no_gate_prob`` is
    replaced by poses that see no gate.

    Args:
        ranges: the recipe's ``[poses]`` section.
        rng: the only source of randomness (same state => same poses).
        track: the scene's track.
        camera: the scene's camera (its uptilt aims the body; its FOV decides what is in view).
        n: number of poses.

    Returns:
        :class:`Poses` of length n, in frame order.
    """
    poses = approach_poses(ranges, rng, track, camera, n)
    empty = np.flatnonzero(rng.random(n) < ranges.no_gate_prob)
    if len(empty):
        other = no_gate_poses(ranges, rng, track, camera, len(empty))
        poses.pos[empty], poses.quat[empty], poses.target[empty] = other.pos, other.quat, -1
    return poses
