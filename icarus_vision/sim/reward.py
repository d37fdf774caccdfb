"""Named reward terms, each a pure batched function; ``compute_reward`` weights and sums them.

Every term is reported separately in ``info["reward_terms"]`` so training curves can show which
term drives learning.
"""

from __future__ import annotations

import numpy as np

from icarus_vision.sim.config import RewardConfig


def reward_progress(prev_dist: np.ndarray, dist: np.ndarray) -> np.ndarray:
    """(N,) metres gained toward the target gate this step (previous − current distance)."""
    return prev_dist - dist


def reward_gate(passed: np.ndarray) -> np.ndarray:
    """(N,) 1 where a gate was passed this step."""
    return passed.astype(np.float64)


def cost_crash(crashed: np.ndarray) -> np.ndarray:
    """(N,) 1 on the step of a crash."""
    return crashed.astype(np.float64)


def cost_attitude(rpy: np.ndarray) -> np.ndarray:
    """(N,) |roll| + |pitch|, radians."""
    return np.abs(rpy[:, 0]) + np.abs(rpy[:, 1])


def reward_speed(vel: np.ndarray, to_gate: np.ndarray) -> np.ndarray:
    """(N,) velocity component toward the target gate, m/s."""
    n = np.linalg.norm(to_gate, axis=1, keepdims=True)
    return np.einsum("ij,ij->i", vel, to_gate / np.maximum(n, 1e-6))


def reward_line(
    p0: np.ndarray, p1: np.ndarray, seg_from: np.ndarray, gate: np.ndarray
) -> np.ndarray:
    """(N,) metres gained along the racing line this step.

    Args:
        p0, p1: (N, 3) positions before and after the step.
        seg_from: (N, 3) start of each drone's segment: the previous gate, or the start position.
        gate: (N, 3) the target gate's centre, the segment's end.

    Progress is the change of the position's projection on the segment, clamped to the segment
    (0 to its length): flying on past the gate's plane beside the gate earns nothing more, and
    coming back costs what it earned. Where the segment is shorter than 1 m (a gate flown straight
    back), the distance gained toward the gate instead.
    """
    seg = gate - seg_from
    length = np.linalg.norm(seg, axis=1)
    unit = seg / np.maximum(length, 1e-9)[:, None]
    s0 = np.clip(np.einsum("ij,ij->i", p0 - seg_from, unit), 0.0, length)
    s1 = np.clip(np.einsum("ij,ij->i", p1 - seg_from, unit), 0.0, length)
    toward = np.linalg.norm(gate - p0, axis=1) - np.linalg.norm(gate - p1, axis=1)
    return np.where(length >= 1.0, s1 - s0, toward)


def path_position(p: np.ndarray, path: np.ndarray, arc: np.ndarray) -> np.ndarray:
    """(N,) how far along each drone's reference path its position lies, metres.

    Args:
        p: (N, 3) positions.
        path: (N, M + 1, 3) each drone's polyline (repeated points allowed).
        arc: (N, M + 1) arc length at each of its points, from 0.

    The position's nearest point on the polyline (each piece's projection clamped to the piece),
    and the arc length there: 0 before the path's start, its length beyond its end.
    """
    a, d = path[:, :-1], np.diff(path, axis=1)  # (N, M, 3) piece starts and directions
    dd = np.maximum(np.einsum("nmk,nmk->nm", d, d), 1e-12)
    u = np.clip(np.einsum("nmk,nmk->nm", p[:, None] - a, d) / dd, 0.0, 1.0)
    near = a + u[..., None] * d
    best = np.argmin(np.einsum("nmk,nmk->nm", p[:, None] - near, p[:, None] - near), axis=1)
    rows = np.arange(len(p))
    return arc[rows, best] + u[rows, best] * (arc[rows, best + 1] - arc[rows, best])


def reward_path(p0: np.ndarray, p1: np.ndarray, path: np.ndarray, arc: np.ndarray) -> np.ndarray:
    """(N,) metres gained along each drone's reference path this step (``path_position`` after
    minus before): a wide line earns the same metres in more steps, a tight one sooner."""
    return path_position(p1, path, arc) - path_position(p0, path, arc)


def camera_gate_angle(rot: np.ndarray, to_gate: np.ndarray, uptilt_rad: float) -> np.ndarray:
    """(N,) angle between the camera's optical axis and the direction to the gate, radians.

    Args:
        rot: (N, 3, 3) body-to-world rotations.
        to_gate: (N, 3) world vector from the drone to the gate.
        uptilt_rad: camera pitch above the body's x axis.
    """
    axis_body = np.array([np.cos(uptilt_rad), 0.0, np.sin(uptilt_rad)])
    axis = rot @ axis_body
    n = np.linalg.norm(to_gate, axis=1)
    cos = np.einsum("ij,ij->i", axis, to_gate) / np.maximum(n, 1e-9)
    return np.arccos(np.clip(cos, -1.0, 1.0))


def cost_perception(angle: np.ndarray, cone_rad: float) -> np.ndarray:
    """(N,) radians by which the gate lies outside the free cone around the optical axis."""
    return np.maximum(angle - cone_rad, 0.0)


def cost_rates(omega: np.ndarray) -> np.ndarray:
    """(N,) body-rate magnitude, rad/s."""
    return np.linalg.norm(omega, axis=1)


def cost_action_change(action: np.ndarray, prev_action: np.ndarray) -> np.ndarray:
    """(N,) squared change of the action; 0 where there is no previous action (NaN rows)."""
    d = np.sum((action - prev_action) ** 2, axis=1)
    return np.where(np.isnan(d), 0.0, d)


def compute_reward(
    cfg: RewardConfig,
    *,
    prev_dist: np.ndarray,
    dist: np.ndarray,
    passed: np.ndarray,
    crashed: np.ndarray,
    rpy: np.ndarray,
    vel: np.ndarray,
    to_gate: np.ndarray,
    dt: float,
    line: np.ndarray | None = None,
    path: np.ndarray | None = None,
    camera_angle: np.ndarray | None = None,
    omega: np.ndarray | None = None,
    action_change: np.ndarray | None = None,
    centrality: np.ndarray | None = None,
    alignment: np.ndarray | None = None,
) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Weighted sum of the named terms.

    The optional inputs are needed only when their term's weight is non-zero: ``line`` (N,) from
    ``reward_line``, ``path`` (N,) from ``reward_path``, ``camera_angle`` (N,) from
    ``camera_gate_angle``, ``omega`` (N, 3) body rates,
    ``action_change`` (N,) from ``cost_action_change``, ``centrality`` (N,) from
    ``rules.gate_crossing`` (0 where no gate was passed), ``alignment`` (N,) from
    ``rules.crossing_alignment`` (0 where no gate was passed).

    Returns:
        reward: (N,) float64.
        terms: name -> (N,) weighted contribution of each term (zero-weight terms omitted).
    """
    terms = {}
    if cfg.progress:
        terms["progress"] = cfg.progress * reward_progress(prev_dist, dist)
    terms["gate"] = cfg.gate * reward_gate(passed)
    terms["crash"] = cfg.crash * cost_crash(crashed)
    if cfg.attitude:
        terms["attitude"] = cfg.attitude * cost_attitude(rpy)
    if cfg.speed:
        terms["speed"] = cfg.speed * reward_speed(vel, to_gate) * dt
    if cfg.time:
        terms["time"] = np.full(dist.shape, cfg.time * dt)
    if cfg.line:
        terms["line"] = cfg.line * line
    if cfg.path:
        terms["path"] = cfg.path * path
    if cfg.perception:
        cone = np.radians(cfg.perception_cone_deg)
        terms["perception"] = cfg.perception * cost_perception(camera_angle, cone)
    if cfg.rates:
        terms["rates"] = cfg.rates * cost_rates(omega)
    if cfg.action_change:
        terms["action_change"] = cfg.action_change * action_change
    if cfg.center:
        terms["center"] = cfg.center * centrality
    if cfg.align:
        terms["align"] = cfg.align * alignment
    total = sum(terms.values())
    return total, terms
