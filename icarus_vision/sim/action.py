"""Action checking: the four-entry command every backend accepts.

Actions are ``[thrust, roll_rate, pitch_rate, yaw_rate]`` in [-1, 1]; finite out-of-range values are
clipped, a wrong shape or NaN/inf raises ``ValueError``.
"""

from __future__ import annotations

import numpy as np


def validate_action(action, n: int) -> np.ndarray:
    """Check and clip actions.

    Args:
        action: array-like (n, 4) (or (4,) when n == 1) in [-1, 1].

    Returns:
        (n, 4) float64 clipped to [-1, 1].

    Raises:
        ValueError: wrong shape, or NaN / inf entries.
    """
    a = np.asarray(action, dtype=np.float64)
    if n == 1 and a.shape == (4,):
        a = a[None]
    if a.shape != (n, 4):
        want = "(4,)" if n == 1 else f"({n}, 4)"
        raise ValueError(
            f"action must have shape {want} [thrust, roll_rate, pitch_rate, yaw_rate], got {a.shape}"
        )
    if not np.all(np.isfinite(a)):
        raise ValueError(
            f"action contains NaN or inf: {a[~np.isfinite(a).all(axis=1)][0].tolist()}"
        )
    return np.clip(a, -1.0, 1.0)


__all__ = ["validate_action"]
