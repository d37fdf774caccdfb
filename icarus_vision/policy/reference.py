"""The plan as the policy reads it: a specialist's features from its track's time-optimal plan.

A specialist flies one known track, whose time-optimal plan (``planning.plan``) says how the
quadrotor flies it at the limit: where, how fast, at what attitude and thrust. These features give
the policy the plan's state at the plan's node nearest the drone on the way to the gate it is
flying to, so it does not have to discover the plan's speed profile by trial, only how far from it
the drone it meets (its mass, the wind, the gates' placement) lets it fly:

    offset to the node (3, heading frame, / ``NEAR_SCALE``), the node's velocity (3, / VEL_SCALE),
    the velocity ``AHEAD_S`` later along the plan (3, / VEL_SCALE), the node's thrust axis (3, body
    z in the heading frame) and its collective thrust (1, fraction of the maximum)

— ``REFERENCE_DIM`` entries, appended after the feature transform's (``features.py``), so a policy
without them is fine-tuned with them by zero first-layer weights. The gate being flown to is found
from the observation (the drone's position plus the next gate's vector, and its passage direction)
as the plan's passage nearest it; where a gate is passed more than once (a hairpin, laps) the
nearest node of every matching passage counts. The reference travels in the exported policy's
file (tensors ``ref.*``), so an exported specialist stays a pure function of its observation.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from icarus_vision.policy.features import (
    CLIP,
    NEAR_SCALE,
    VEL_SCALE,
    _yaw_frame,
    passage_heading,
)
from icarus_vision.sim.dynamics import quat_to_rot

REFERENCE_DIM = 13
"""Entries of the plan features."""
AHEAD_S = 0.3
"""How far ahead along the plan (s) the second velocity is read."""
MATCH_SLACK = 0.5
"""Passages whose match cost is within this of the best one's are all searched for the nearest
node (the same gate flown again); the cost is the distance to the passage's centre (m) plus
2 × (1 − cosine) of the heading difference."""
MAX_MATCHES = 4
"""Most passages searched for the nearest node (a gate flown up to this many times)."""
REFERENCE_KEYS = ("gate_pos", "gate_dir", "pos", "vel", "vel_ahead", "z_axis", "thrust")


@dataclass(frozen=True, eq=False)
class PlanReference:
    """A track's plan cut into the segments leading to each of its S passages, M nodes each
    (shorter segments repeat their last node).

    Attributes:
        gate_pos: (S, 3) each passage's gate centre.
        gate_dir: (S, 2) each passage's direction (cos, sin of its yaw).
        pos, vel, vel_ahead, z_axis: (S, M, 3) each segment's node positions, velocities,
            velocities ``AHEAD_S`` later and thrust axes (world frame).
        thrust: (S, M) collective thrust at each node, fraction of the maximum.
    """

    gate_pos: np.ndarray
    gate_dir: np.ndarray
    pos: np.ndarray
    vel: np.ndarray
    vel_ahead: np.ndarray
    z_axis: np.ndarray
    thrust: np.ndarray
    dim = REFERENCE_DIM

    def __post_init__(self) -> None:
        s = len(self.gate_pos)
        shapes = {"gate_pos": (s, 3), "gate_dir": (s, 2), "thrust": self.pos.shape[:2]}
        shapes |= {k: (s, self.pos.shape[1], 3) for k in ("pos", "vel", "vel_ahead", "z_axis")}
        for key, shape in shapes.items():
            a = getattr(self, key)
            if s == 0 or a.shape != shape or not np.all(np.isfinite(a)):
                raise ValueError(
                    f"plan reference: {key} must be finite of shape {shape}, got {a.shape}"
                )

    @classmethod
    def from_plan(cls, plan, track, thrust_max: float) -> PlanReference:
        """The reference of ``plan`` (a ``planning.PlanResult`` of ``track``, all laps) for a
        quadrotor of maximum collective thrust ``thrust_max`` (N)."""
        passages = track.passages
        nodes = np.asarray(plan.gate_nodes, dtype=np.int64)
        if len(nodes) != len(passages):
            raise ValueError(
                f"plan of {len(nodes)} passages for a track of {len(passages)} ({track.name})"
            )
        t, pos, vel = (np.asarray(a, dtype=np.float64) for a in (plan.t, plan.pos, plan.vel))
        z_axis = quat_to_rot(np.asarray(plan.quat, dtype=np.float64))[:, :, 2]
        thrust = np.asarray(plan.thrust, dtype=np.float64) / thrust_max
        t_ahead = np.minimum(t + AHEAD_S, t[-1])
        vel_ahead = np.stack([np.interp(t_ahead, t, vel[:, i]) for i in range(3)], axis=1)
        starts = np.concatenate([[0], nodes[:-1]])
        m = int(np.max(nodes - starts)) + 1
        idx = np.minimum(starts[:, None] + np.arange(m), nodes[:, None])  # (S, M), padded
        yaw = np.array([g.yaw for g in passages])
        return cls(
            gate_pos=np.array([g.pos for g in passages], dtype=np.float64),
            gate_dir=np.stack((np.cos(yaw), np.sin(yaw)), axis=1),
            pos=pos[idx], vel=vel[idx], vel_ahead=vel_ahead[idx], z_axis=z_axis[idx],
            thrust=thrust[idx],
        )  # fmt: skip

    def tensors(self) -> dict[str, np.ndarray]:
        """The arrays for a safetensors file (``ref.NAME``, float32)."""
        return {f"ref.{k}": getattr(self, k).astype(np.float32) for k in REFERENCE_KEYS}

    @classmethod
    def from_tensors(cls, tensors: dict[str, np.ndarray]) -> PlanReference:
        """Inverse of ``tensors``; ``ValueError`` when an array is missing or malformed."""
        missing = [k for k in REFERENCE_KEYS if f"ref.{k}" not in tensors]
        if missing:
            raise ValueError(f"plan reference: missing tensors {', '.join(missing)}")
        return cls(**{k: np.asarray(tensors[f"ref.{k}"], np.float64) for k in REFERENCE_KEYS})

    def gate_distance(self, points: np.ndarray) -> np.ndarray:
        """(K,) distance of each of ``points`` (K, 3) to the nearest planned passage's gate."""
        return np.min(np.linalg.norm(points[:, None] - self.gate_pos[None], axis=2), axis=1)

    def nearest(self, obs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(passage, node) of the reference node nearest each drone on the way to its gate.

        Args:
            obs: (N, 21) or (N, 25) world-frame observations (the passage direction is needed).
        """
        p = obs[:, 0:3]
        gate = p + obs[:, 12:15]
        cost = np.linalg.norm(gate[:, None, :] - self.gate_pos[None], axis=2)
        cost += 2.0 * (1.0 - passage_heading(obs) @ self.gate_dir.T)  # (N, S)
        cand = np.argsort(cost, axis=1)[:, :MAX_MATCHES]  # (N, C) the best passages first
        best = np.take_along_axis(cost, cand, axis=1)
        match = best <= best[:, :1] + MATCH_SLACK  # as good as the best: the same gate
        used = int(match.sum(axis=1).max())  # sorted, so the matches come first
        cand, match = cand[:, :used], match[:, :used]
        d2 = np.sum((self.pos[cand] - p[:, None, None, :]) ** 2, axis=3)  # (N, C, M)
        d2[~match] = np.inf
        c, node = np.divmod(np.argmin(d2.reshape(len(obs), -1), axis=1), self.pos.shape[1])
        return cand[np.arange(len(obs)), c], node

    def features(self, obs: np.ndarray) -> np.ndarray:
        """(N, ``REFERENCE_DIM``) float32 plan features of world-frame observations (module doc).

        Raises:
            ValueError: an observation without the next gate's passage direction (15 entries).
        """
        obs = np.asarray(obs, dtype=np.float64)
        if obs.ndim != 2 or obs.shape[1] < 21:
            raise ValueError(
                f"plan features need extended or racing observations (N, 21 or 25), got {obs.shape}"
            )
        s, k = self.nearest(obs)
        yaw = obs[:, 8]
        c, sn = np.cos(yaw), np.sin(yaw)
        out = np.concatenate(
            (
                _yaw_frame(self.pos[s, k] - obs[:, 0:3], c, sn) / NEAR_SCALE,
                _yaw_frame(self.vel[s, k], c, sn) / VEL_SCALE,
                _yaw_frame(self.vel_ahead[s, k], c, sn) / VEL_SCALE,
                _yaw_frame(self.z_axis[s, k], c, sn),
                self.thrust[s, k][:, None],
            ),
            axis=1,
        )
        return np.clip(out, -CLIP, CLIP).astype(np.float32)


__all__ = ["AHEAD_S", "REFERENCE_DIM", "PlanReference"]
