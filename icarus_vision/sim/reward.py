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
) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Weighted sum of the named terms.

    Returns:
        reward: (N,) float64.
        terms: name -> (N,) weighted contribution of each term (zero-weight terms omitted).
    """
    terms = {
        "progress": cfg.progress * reward_progress(prev_dist, dist),
        "gate": cfg.gate * reward_gate(passed),
        "crash": cfg.crash * cost_crash(crashed),
        "attitude": cfg.attitude * cost_attitude(rpy),
    }
    if cfg.speed:
        terms["speed"] = cfg.speed * reward_speed(vel, to_gate) * dt
    if cfg.time:
        terms["time"] = np.full(dist.shape, cfg.time * dt)
    total = sum(terms.values())
    return total, terms
