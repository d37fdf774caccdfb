"""Per-detection geometry: corner checks, square PnP with its two-fold ambiguity, and the noise model.

Frames (ARCHITECTURE.md): the gate frame has x along the passage direction, y left, z up, origin at
the opening's centre; the camera frame is OpenCV's optical frame (x right, y down, z forward).
OpenCV's IPPE square solver wants the target in its own z = 0 plane with the corners in the order
(-h, h), (h, h), (h, -h), (-h, -h); :data:`R_GATE_SQUARE` maps that frame onto the gate frame so
that TL, TR, BR, BL line up.

A planar square seen in perspective has two poses that explain its corners almost equally well (the
plane flipped about the line of sight). :func:`solve_square_pnp` returns both with their
reprojection errors; :func:`solution_costs` scores them by reprojection error, by how far each tilts
the gate away from vertical (gates stand upright), and by a heading prior when one is known.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import cv2
import numpy as np

from icarus_vision.estimator.config import MeasurementConfig

# Columns: the square target's axes (x, y, z of OpenCV's IPPE_SQUARE object frame) in the gate frame.
R_GATE_SQUARE = np.array([[0.0, 0.0, -1.0], [-1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])

_R_SQUARE_GATE = R_GATE_SQUARE.T.copy()
_EYE3 = np.eye(3)
_EYE6 = np.eye(6)
_HALF_PI = math.pi / 2
# -[r]× = [[0, rz, -ry], [-rz, 0, rx], [ry, -rx, 0]], flattened: r[_SKEW_INDEX] * _NEG_SKEW_SIGN.
_SKEW_INDEX = np.array([0, 2, 1, 2, 0, 0, 1, 0, 0])
_NEG_SKEW_SIGN = np.array([0.0, 1.0, -1.0, -1.0, 0.0, 1.0, 1.0, -1.0, 0.0])

REJECT_REASONS = ("non_finite", "outside_image", "too_small", "degenerate", "pnp_failed", "range")
"""Why a detection can be rejected before the filter sees it (counted by the estimator)."""


def gate_points(size: float) -> np.ndarray:
    """(4, 3) opening corners TL, TR, BR, BL in the gate frame, m."""
    h = size / 2.0
    return np.array([[0.0, h, h], [0.0, -h, h], [0.0, -h, -h], [0.0, h, -h]])


@functools.cache
def _square_points(size: float) -> np.ndarray:
    h = size / 2.0
    points = np.array([[-h, h, 0.0], [h, h, 0.0], [h, -h, 0.0], [-h, -h, 0.0]])
    points.flags.writeable = False  # shared between calls
    return points


def check_corners(
    corners: np.ndarray, width: int, height: int, cfg: MeasurementConfig
) -> str | None:
    """Why a detection's corners cannot be solved, or None when they can.

    Args:
        corners: (4, 2) pixels, TL, TR, BR, BL.
        width, height: image size, pixels.

    Returns:
        one of :data:`REJECT_REASONS` (non_finite, outside_image, too_small, degenerate) or None.
        ``degenerate`` covers collinear corners, a crossed (non-convex) quadrilateral and a winding
        that mirrors the gate.
    """
    c = np.asarray(corners, dtype=float)
    if c.shape != (4, 2):
        return "non_finite"
    (u0, v0), (u1, v1), (u2, v2), (u3, v3) = c.tolist()  # plain floats: 8 numbers, no numpy calls
    if not all(map(math.isfinite, (u0, v0, u1, v1, u2, v2, u3, v3))):
        return "non_finite"
    lo, m = -0.5 - cfg.image_margin_px, cfg.image_margin_px
    if min(u0, u1, u2, u3, v0, v1, v2, v3) < lo:
        return "outside_image"
    if max(u0, u1, u2, u3) > width - 0.5 + m or max(v0, v1, v2, v3) > height - 0.5 + m:
        return "outside_image"
    us, vs = (u0, u1, u2, u3), (v0, v1, v2, v3)
    sides = sum(math.hypot(us[(i + 1) % 4] - us[i], vs[(i + 1) % 4] - vs[i]) for i in range(4))
    if sides / 4.0 < cfg.min_side_px:
        return "too_small"
    # Signed areas of the four corner triangles (i-1, i, i+1): TL, TR, BR, BL runs clockwise on
    # screen (v down), i.e. positive in this (u, v) orientation; all must share that sign (convex,
    # not crossed, not mirrored) and none may be thin (three corners nearly collinear).
    quad = 0.5 * sum(us[i] * vs[(i + 1) % 4] - us[(i + 1) % 4] * vs[i] for i in range(4))
    if quad <= 0:
        return "degenerate"
    for i in range(4):
        a, b = (i + 1) % 4, (i + 3) % 4
        tri = 0.5 * ((us[a] - us[i]) * (vs[b] - vs[i]) - (vs[a] - vs[i]) * (us[b] - us[i]))
        if tri < cfg.min_area_ratio * quad:
            return "degenerate"
    return None


@dataclass(frozen=True)
class PnPSolution:
    """One pose of the gate in the camera frame.

    Attributes:
        r_cam_gate: (3, 3) gate axes (x passage, y left, z up) in the camera optical frame.
        t_cam_gate: (3,) gate centre in the camera optical frame, m.
        sq_err: sum of squared reprojection residuals over the 8 corner coordinates, px².
    """

    r_cam_gate: np.ndarray
    t_cam_gate: np.ndarray
    sq_err: float


def solve_square_pnp(corners: np.ndarray, size: float, k: np.ndarray) -> list[PnPSolution]:
    """Both IPPE solutions for a square gate opening (best reprojection first).

    Args:
        corners: (4, 2) pixels, TL, TR, BR, BL (checked with :func:`check_corners`).
        size: side of the opening, m.
        k: (3, 3) camera intrinsics (no distortion).

    Returns:
        up to two solutions with the gate in front of the camera; empty when OpenCV fails.
    """
    obj = _square_points(size)
    img = np.ascontiguousarray(corners, dtype=np.float64).reshape(4, 1, 2)
    try:
        n, rvecs, tvecs, errs = cv2.solvePnPGeneric(
            obj, img, k, None, flags=cv2.SOLVEPNP_IPPE_SQUARE
        )
    except cv2.error:
        return []
    out = []
    for i in range(n):
        t = tvecs[i].reshape(3)
        tx, ty, tz = t.tolist()
        if not (math.isfinite(tx) and math.isfinite(ty) and math.isfinite(tz) and tz > 0):
            continue
        r_cam_square, _ = cv2.Rodrigues(rvecs[i])
        # OpenCV reports the RMS over the 8 coordinates.
        out.append(PnPSolution(r_cam_square @ _R_SQUARE_GATE, t, 8.0 * float(errs[i, 0]) ** 2))
    out.sort(key=lambda s: s.sq_err)
    return out


def pose_covariance(
    k: np.ndarray, r_cam_gate: np.ndarray, t_cam_gate: np.ndarray, size: float, sigma_px: float
) -> np.ndarray:
    """First-order covariance of PnP poses from independent corner noise of σ pixels.

    The pose is perturbed as p_cam = exp([δθ]×) R p_gate + t + δt (δθ about the gate centre, camera
    axes), so the covariance's first block is directly the gate centre's. It grows with distance
    (the square of it along the line of sight) and with the viewing angle (foreshortening).

    Args:
        k: (3, 3) camera intrinsics.
        r_cam_gate: (..., 3, 3) gate axes in the camera frame; t_cam_gate: (..., 3) its centre, m.
        size: side of the opening, m.

    Returns:
        (..., 6, 6) covariance of (δt, δθ) in the camera frame, m² and rad².
    """
    rp = gate_points(size) @ np.swapaxes(r_cam_gate, -1, -2)  # (..., 4, 3) corner offsets, camera
    pc = rp + t_cam_gate[..., None, :]
    x, y, iz = pc[..., 0], pc[..., 1], 1.0 / pc[..., 2]
    fx, fy = k[0, 0], k[1, 1]
    # Chain rule per corner: d(u, v)/d(point) (2, 3), then d(point)/d(δt, δθ) = [I, -[rp]×] (3, 6).
    a, b = fx * iz, -fx * x * iz * iz  # du/dx, du/dz
    c, d = fy * iz, -fy * y * iz * iz  # dv/dy, dv/dz
    proj = np.zeros((*a.shape, 2, 3))
    proj[..., 0, 0], proj[..., 0, 2], proj[..., 1, 1], proj[..., 1, 2] = a, b, c, d
    lever = np.empty((*a.shape, 3, 6))
    lever[..., :3] = _EYE3
    lever[..., 3:] = (rp[..., _SKEW_INDEX] * _NEG_SKEW_SIGN).reshape(*a.shape, 3, 3)
    jac = (proj @ lever).reshape(*a.shape[:-1], 8, 6)
    info = np.swapaxes(jac, -1, -2) @ jac / sigma_px**2
    return np.linalg.inv(info + 1e-12 * _EYE6)


def gate_yaw(r_world_gate: np.ndarray) -> float:
    """Heading (radians) of the gate's x axis about world z."""
    return math.atan2(r_world_gate[1, 0], r_world_gate[0, 0])


def wrap_axis(angle: np.ndarray | float) -> np.ndarray | float:
    """Wrap an angle between two axes (headings modulo π) into [-π/2, π/2).

    A Python float comes back as a float (the same value, without numpy's per-call cost).
    """
    if isinstance(angle, float):
        return (angle + _HALF_PI) % math.pi - _HALF_PI
    return (np.asarray(angle) + np.pi / 2) % np.pi - np.pi / 2


@dataclass(frozen=True)
class GateMeasurement:
    """A gate pose measured in one frame, in the odometry world frame.

    Attributes:
        pos: (3,) gate centre, m.
        yaw: heading of the gate's x axis about world z, rad (the passage facing the camera).
        cov: (4, 4) covariance of (pos, yaw), m² / rad².
        distance: camera to gate centre, m.
        cost: ambiguity score of the chosen solution (lower is better); see :func:`solution_costs`.
    """

    pos: np.ndarray
    yaw: float
    cov: np.ndarray
    distance: float
    cost: float


def solution_costs(
    solutions: list[PnPSolution],
    r_world_cam: np.ndarray,
    cfg: MeasurementConfig,
    prior_yaw: float | None = None,
    prior_yaw_sigma: float | None = None,
) -> np.ndarray:
    """Ambiguity score of each solution (lower is better).

    reprojection residual / σ² + (tilt from vertical / σ_tilt)² [+ (heading − prior, modulo π)² / σ²].
    """
    costs = []
    for s in solutions:
        r_wg = r_world_cam @ s.r_cam_gate
        tilt = math.acos(min(1.0, max(-1.0, r_wg[2, 2])))
        c = s.sq_err / cfg.pixel_sigma**2 + (tilt / math.radians(cfg.tilt_sigma_deg)) ** 2
        if prior_yaw is not None and prior_yaw_sigma is not None:
            c += (float(wrap_axis(gate_yaw(r_wg) - prior_yaw)) / prior_yaw_sigma) ** 2
        costs.append(c)
    return np.array(costs)


def scale_covariance(cov6: np.ndarray, size: float) -> np.ndarray:
    """:func:`pose_covariance` (..., 6, 6) of a unit gate -> that of a gate of side ``size``."""
    d = np.array([size, size, size, 1.0, 1.0, 1.0])
    return cov6 * d[:, None] * d[None, :]


def measurement_covariance(
    cov6: np.ndarray,
    distance: np.ndarray | float,
    r_world_cam: np.ndarray,
    cfg: MeasurementConfig,
) -> np.ndarray:
    """(..., 4, 4) covariance of world-frame (position, heading) measurements.

    Args:
        cov6: (..., 6, 6) :func:`pose_covariance` of the solutions (before ``cfg.cov_scale`` and
            the range inflation ``1 + (distance / cfg.range_inflation_m)²``).
        distance: (...) camera to gate centre, m (lever arm of the odometry's attitude error).
        r_world_cam: (3, 3) camera attitude from odometry (and the mount).
    """
    scale = cfg.cov_scale * (1.0 + (np.asarray(distance) / cfg.range_inflation_m) ** 2)
    cov6 = cov6 * scale[..., None, None]
    att = math.radians(cfg.odometry_att_sigma_deg)
    floor = (att * np.asarray(distance)) ** 2 + cfg.min_sigma_m**2
    up_cam = r_world_cam[2]  # world z in camera axes
    cov = np.empty((*cov6.shape[:-2], 4, 4))
    cov[..., :3, :3] = r_world_cam @ cov6[..., :3, :3] @ r_world_cam.T
    cov[..., :3, :3] += floor[..., None, None] * _EYE3
    if cfg.heading_correlation:
        cross = (cov6[..., :3, 3:] @ up_cam) @ r_world_cam.T  # R (C_tθ up), as rows
        cov[..., :3, 3] = cov[..., 3, :3] = cross
    else:
        cov[..., :3, 3] = cov[..., 3, :3] = 0.0
    cov[..., 3, 3] = (cov6[..., 3:, 3:] @ up_cam) @ up_cam + att**2
    return cov


def world_pose(
    r_cam_gate: np.ndarray,
    t_cam_gate: np.ndarray,
    r_world_cam: np.ndarray,
    t_world_cam: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Camera-frame gate poses in the odometry world frame.

    Args:
        r_cam_gate: (..., 3, 3) gate axes, t_cam_gate: (..., 3) gate centres, camera frame.
        r_world_cam: (3, 3), t_world_cam: (3,) camera pose from odometry (and the mount).

    Returns:
        (..., 3) gate centres (m) and (...) headings of the gates' x axes about world z (rad).
    """
    pos = t_cam_gate @ r_world_cam.T + t_world_cam
    x_axis = r_cam_gate[..., 0] @ r_world_cam.T  # the gates' x axes, world frame
    return pos, np.arctan2(x_axis[..., 1], x_axis[..., 0])


def to_measurement(
    sol: PnPSolution,
    cov: np.ndarray,
    r_world_cam: np.ndarray,
    t_world_cam: np.ndarray,
    cost: float = 0.0,
) -> GateMeasurement:
    """Express a camera-frame solution in the odometry world frame.

    Args:
        sol: the solution, for the gate's true size.
        cov: (4, 4) its :func:`measurement_covariance`.
        r_world_cam: (3, 3), t_world_cam: (3,) camera pose from odometry (and the mount).
    """
    dist = math.sqrt(float(sol.t_cam_gate @ sol.t_cam_gate))
    pos, yaw = world_pose(sol.r_cam_gate, sol.t_cam_gate, r_world_cam, t_world_cam)
    return GateMeasurement(pos, float(yaw), cov, dist, cost)


def measure_candidates(
    corners: np.ndarray,
    size: float,
    k: np.ndarray,
    r_world_cam: np.ndarray,
    t_world_cam: np.ndarray,
    cfg: MeasurementConfig,
) -> tuple[list[PnPSolution], np.ndarray]:
    """PnP solutions of one detection with their prior-free ambiguity costs (best first).

    A solution whose cost exceeds the best one's by more than ``cfg.ambiguity_gap`` is dropped.
    """
    sols = solve_square_pnp(corners, size, k)
    if not sols:
        return [], np.zeros(0)
    costs = solution_costs(sols, r_world_cam, cfg)
    order, c = np.argsort(costs).tolist(), costs.tolist()
    keep = [i for i in order if c[i] - c[order[0]] <= cfg.ambiguity_gap]
    return [sols[i] for i in keep], costs[keep]
