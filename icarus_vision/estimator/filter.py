"""Kalman filter on one gate's pose: position (3) and heading axis (1) in the odometry world frame.

A gate does not move, but the odometry frame it is expressed in drifts: prediction keeps the mean
and adds a random walk of the configured density. The heading is an axis (a square opening looks the
same from both sides), so its innovation is wrapped modulo π.
"""

from __future__ import annotations

import math
from collections import deque

import numpy as np

from icarus_vision.estimator.config import FilterConfig
from icarus_vision.estimator.pnp import GateMeasurement, wrap_axis

_EYE4 = np.eye(4)


def process_noise(cfg: FilterConfig) -> np.ndarray:
    """(4,) variance added per second to (x, y, z, heading) by odometry drift."""
    yaw = math.radians(cfg.yaw_process_deg_per_sqrt_s) ** 2
    return np.array([cfg.pos_process_m_per_sqrt_s**2] * 3 + [yaw])


def kf_predict(cov: np.ndarray, dt: float, cfg: FilterConfig) -> np.ndarray:
    """(4, 4) covariance after ``dt`` seconds of odometry drift (the mean is unchanged)."""
    return cov + np.diag(process_noise(cfg) * max(dt, 0.0))


def innovation(mean: np.ndarray, z: GateMeasurement) -> np.ndarray:
    """(4,) measurement minus prediction, heading wrapped modulo π."""
    nu = np.empty(4)
    nu[:3] = z.pos - mean[:3]
    nu[3] = wrap_axis(z.yaw - mean[3])
    return nu


def mahalanobis_sq(mean: np.ndarray, cov: np.ndarray, z: GateMeasurement) -> float:
    """Squared Mahalanobis distance of a measurement from the prediction (χ², 4 dof)."""
    nu = innovation(mean, z)
    return float(nu @ np.linalg.solve(cov + z.cov, nu))


def batch_mahalanobis_sq(
    means: np.ndarray, covs: np.ndarray, z: np.ndarray, r: np.ndarray
) -> np.ndarray:
    """Squared Mahalanobis distances of measurements from M gate predictions.

    Args:
        means: (M, 4) gate states; covs: (M, 4, 4) their covariances.
        z: (..., K, 4) measured positions and headings, K alternatives sharing a covariance.
        r: (..., 4, 4) the covariance of each K alternatives.

    Returns:
        (..., K, M) χ² values (4 dof).
    """
    nu = z[..., None, :, :] - means[:, None, :]  # (..., M, K, 4)
    nu[..., 3] = wrap_axis(nu[..., 3])
    sol = np.linalg.solve(covs + r[..., None, :, :], np.swapaxes(nu, -1, -2))  # (..., M, 4, K)
    return np.einsum("...mki,...mik->...km", nu, sol)


def kf_update(
    mean: np.ndarray, cov: np.ndarray, z: np.ndarray, r: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Kalman updates with direct measurements of (position, heading) (Joseph form).

    Args:
        mean: (..., 4) and cov: (..., 4, 4) gate states.
        z: (..., 4) measured positions and headings; r: (..., 4, 4) their covariances.

    Returns:
        (..., 4) means and (..., 4, 4) covariances.
    """
    nu = z - mean
    nu[..., 3] = wrap_axis(nu[..., 3])
    gain = np.swapaxes(np.linalg.solve(cov + r, cov), -1, -2)  # cov s⁻¹ (both symmetric)
    new_mean = mean + (gain @ nu[..., None])[..., 0]
    new_mean[..., 3] = wrap_axis(new_mean[..., 3])
    a = _EYE4 - gain
    new_cov = a @ cov @ np.swapaxes(a, -1, -2) + gain @ r @ np.swapaxes(gain, -1, -2)
    return new_mean, 0.5 * (new_cov + np.swapaxes(new_cov, -1, -2))


def heading_spread(yaw: float, alt_yaw: float, gap: float) -> float:
    """Heading variance (rad²) that the other PnP solution adds to a measurement (0 if negligible).

    The heading likelihood is bimodal; with the alternative's weight w = 1 / (1 + exp(gap / 2))
    (``gap``: its score minus the chosen one's, a χ²-like difference) the variance grows by
    w · Δheading², so that ambiguous views cannot make a gate's heading confidently wrong.
    """
    w = 1.0 / (1.0 + math.exp(min(gap, 60.0) / 2.0))
    dyaw = wrap_axis(float(alt_yaw - yaw))
    spread = w * dyaw * dyaw
    return 0.0 if spread < 1e-8 else spread


RECENT_HITS = 32
"""Accepted measurements a track remembers the times of (more than a re-initialisation window
holds at the camera's rate)."""


class GateTrack:
    """The filtered estimate of one physical gate.

    Attributes:
        mean: (4,) x, y, z (m) and heading axis (rad), odometry world frame.
        cov: (4, 4) covariance.
        size: side of the opening, m.
        hits: accepted measurements so far.
        last_hit_t: time of the last accepted measurement, s (-inf if none).
        hit_times: times of the last accepted measurements (at most ``RECENT_HITS``), s.
        created_t: time the track was created, s.
        from_map: initialised from the prior map (map-aided) rather than from vision.
        anchor: (3,) where the track started: the map's place for a gate of the map.
    """

    def __init__(
        self,
        pos: np.ndarray,
        yaw: float,
        cov: np.ndarray,
        size: float,
        t: float,
        from_map: bool,
    ) -> None:
        self.mean = np.array([*np.asarray(pos, dtype=float), float(wrap_axis(yaw))])
        self.cov = np.array(cov, dtype=float)
        self.size = float(size)
        self.hits = 0
        self.last_hit_t = -math.inf
        self.hit_times: deque[float] = deque(maxlen=RECENT_HITS)
        self.created_t = float(t)
        self.from_map = from_map
        self.anchor = self.mean[:3].copy()

    @property
    def pos(self) -> np.ndarray:
        """(3,) estimated centre, odometry world frame, m."""
        return self.mean[:3]

    def predict(self, dt: float, cfg: FilterConfig) -> None:
        self.cov = kf_predict(self.cov, dt, cfg)

    def add_noise(self, q_dt: np.ndarray) -> None:
        """Add a (4, 4) diagonal process noise to the covariance (a prediction, precomputed)."""
        self.cov += q_dt

    def distance_sq(self, z: GateMeasurement) -> float:
        return mahalanobis_sq(self.mean, self.cov, z)

    def update(self, z: GateMeasurement, t: float) -> None:
        update_tracks([self], [z], t)

    def reinit(self, z: GateMeasurement, t: float) -> None:
        """Restart from a measurement (the prior was wrong): the hits before no longer count."""
        self.mean = np.array([*z.pos, float(wrap_axis(z.yaw))])
        self.cov = z.cov.copy()
        self.hit_times.clear()
        self.record_hit(t)

    def record_hit(self, t: float) -> None:
        """Count an accepted measurement at time ``t``."""
        self.hits += 1
        self.last_hit_t = t
        self.hit_times.append(t)

    def hits_since(self, t0: float) -> int:
        """Accepted measurements at or after ``t0`` (counted among the last ``RECENT_HITS``)."""
        return sum(h >= t0 for h in self.hit_times)


def update_tracks(tracks: list[GateTrack], zs: list[GateMeasurement], t: float) -> None:
    """Update distinct gate tracks with one measurement each, at time ``t`` (one batched update)."""
    if not tracks:
        return
    means, covs = kf_update(
        np.array([tr.mean for tr in tracks]),
        np.array([tr.cov for tr in tracks]),
        np.array([[*z.pos.tolist(), z.yaw] for z in zs]),
        np.array([z.cov for z in zs]),
    )
    for tr, mean, cov in zip(tracks, means, covs, strict=True):
        tr.mean, tr.cov = mean, cov
        tr.record_hit(t)
