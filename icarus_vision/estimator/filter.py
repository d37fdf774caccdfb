"""Kalman filter on one gate's pose: position (3) and heading axis (1) in the odometry world frame.

A gate does not move, but the odometry frame it is expressed in drifts: prediction keeps the mean
and adds a random walk of the configured density. The heading is an axis (a square opening looks the
same from both sides), so its innovation is wrapped modulo π.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from icarus_vision.estimator.config import FilterConfig
from icarus_vision.estimator.pnp import GateMeasurement, wrap_axis


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
    means: np.ndarray, covs: np.ndarray, zs: list[GateMeasurement]
) -> np.ndarray:
    """Squared Mahalanobis distances of K measurements from M predictions.

    Args:
        means: (M, 4) gate states; covs: (M, 4, 4) their covariances.
        zs: K measurements.

    Returns:
        (K, M) χ² values (4 dof).
    """
    z = np.array([[*m.pos, m.yaw] for m in zs])  # (K, 4)
    r = np.array([m.cov for m in zs])  # (K, 4, 4)
    nu = z[:, None, :] - means[None]
    nu[..., 3] = wrap_axis(nu[..., 3])
    sol = np.linalg.solve(covs[None] + r[:, None], nu[..., None])[..., 0]
    return np.einsum("kmi,kmi->km", nu, sol)


def kf_update(
    mean: np.ndarray, cov: np.ndarray, z: GateMeasurement
) -> tuple[np.ndarray, np.ndarray]:
    """Kalman update with a direct measurement of (position, heading) (Joseph form).

    Returns:
        (4,) mean and (4, 4) covariance.
    """
    nu = innovation(mean, z)
    s = cov + z.cov
    gain = np.linalg.solve(s, cov).T  # cov s⁻¹ (both symmetric)
    new_mean = mean + gain @ nu
    new_mean[3] = wrap_axis(new_mean[3])
    a = np.eye(4) - gain
    new_cov = a @ cov @ a.T + gain @ z.cov @ gain.T
    return new_mean, 0.5 * (new_cov + new_cov.T)


def widen_heading(m: GateMeasurement, alt: GateMeasurement, gap: float) -> GateMeasurement:
    """Account for the other PnP solution in a measurement's heading variance.

    The heading likelihood is bimodal; with the alternative's weight w = 1 / (1 + exp(gap / 2))
    (``gap``: its score minus the chosen one's, a χ²-like difference) the variance grows by
    w · Δheading², so that ambiguous views cannot make a gate's heading confidently wrong.
    """
    w = 1.0 / (1.0 + math.exp(min(gap, 60.0) / 2.0))
    dyaw = float(wrap_axis(alt.yaw - m.yaw))
    if w * dyaw * dyaw < 1e-8:
        return m
    cov = m.cov.copy()
    cov[3, 3] += w * dyaw * dyaw
    return replace(m, cov=cov)


_DIAG = np.diag_indices(4)


class GateTrack:
    """The filtered estimate of one physical gate.

    Attributes:
        mean: (4,) x, y, z (m) and heading axis (rad), odometry world frame.
        cov: (4, 4) covariance.
        size: side of the opening, m.
        hits: accepted measurements so far.
        last_hit_t: time of the last accepted measurement, s (-inf if none).
        created_t: time the track was created, s.
        from_map: initialised from the prior map (map-aided) rather than from vision.
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
        self.created_t = float(t)
        self.from_map = from_map

    @property
    def pos(self) -> np.ndarray:
        """(3,) estimated centre, odometry world frame, m."""
        return self.mean[:3]

    def predict(self, dt: float, cfg: FilterConfig) -> None:
        self.cov = kf_predict(self.cov, dt, cfg)

    def add_noise(self, q_dt: np.ndarray) -> None:
        """Add (4,) variances to the diagonal (a prediction with precomputed process noise)."""
        self.cov[_DIAG] += q_dt

    def distance_sq(self, z: GateMeasurement) -> float:
        return mahalanobis_sq(self.mean, self.cov, z)

    def update(self, z: GateMeasurement, t: float) -> None:
        self.mean, self.cov = kf_update(self.mean, self.cov, z)
        self.hits += 1
        self.last_hit_t = t

    def reinit(self, z: GateMeasurement, t: float) -> None:
        """Restart from a measurement (the prior was wrong)."""
        self.mean = np.array([*z.pos, float(wrap_axis(z.yaw))])
        self.cov = z.cov.copy()
        self.hits += 1
        self.last_hit_t = t
