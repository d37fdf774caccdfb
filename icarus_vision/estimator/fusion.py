"""One camera frame: detections -> world-frame gate measurements -> the gate track each one fits.

Each detection is checked and solved by square PnP on its own (:mod:`.pnp`, one OpenCV call each);
from there the frame is handled as arrays: the pose covariances of all its detections at once, their
world-frame measurements for each gate size, and the Mahalanobis distances of every PnP solution to
every gate track of that size. A detection has up to two PnP solutions, held in two slots; where the
second is missing its slot repeats the first with an infinite cost, so that it is never chosen.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.optimize import linear_sum_assignment

from icarus_vision.estimator.config import EstimatorConfig, MeasurementConfig
from icarus_vision.estimator.filter import GateTrack, batch_mahalanobis_sq, heading_spread
from icarus_vision.estimator.pnp import (
    GateMeasurement,
    check_corners,
    measure_candidates,
    measurement_covariance,
    pose_covariance,
    scale_covariance,
    world_pose,
)
from icarus_vision.gate_detect.base import GateDetection

# The assignment's cost of a pair outside the gates (never chosen over one inside).
_NOT_ALLOWED = 1e12


@dataclass(frozen=True)
class FrameSolutions:
    """The PnP solutions of a frame's D usable detections, for a gate of unit size, best first.

    Attributes:
        r_cam_gate: (D, 2, 3, 3) gate axes in the camera optical frame, per solution slot.
        t_cam_gate: (D, 2, 3) gate centre in the camera optical frame, m.
        costs: (D, 2) ambiguity costs (:func:`.pnp.solution_costs`), inf in a missing second slot.
        two: (D,) whether the second slot holds a solution.
        cov6: (D, 6, 6) :func:`.pnp.pose_covariance` of the best solutions.
        distance: (D,) camera to the best solution's gate centre, m.
        bearing_sigma: (2,) error of a detection's direction in normalised image coordinates
            (x / z, y / z): its centre's pixels and the odometry's attitude.
    """

    r_cam_gate: np.ndarray
    t_cam_gate: np.ndarray
    costs: np.ndarray
    two: np.ndarray
    cov6: np.ndarray
    distance: np.ndarray
    bearing_sigma: np.ndarray


@dataclass(frozen=True)
class FrameMeasurements:
    """The solutions of a frame scaled to gates of one size, in the odometry world frame.

    Attributes:
        z: (D, 2, 4) gate centre (m) and heading (rad) of each solution slot.
        cov: (D, 4, 4) their covariance (both slots share the best solution's).
        distance: (D, 2) camera to gate centre, m.
    """

    z: np.ndarray
    cov: np.ndarray
    distance: np.ndarray


def solve_detections(
    detections: list[GateDetection],
    k: np.ndarray,
    image_size: tuple[int, int],
    r_world_cam: np.ndarray,
    t_world_cam: np.ndarray,
    cfg: MeasurementConfig,
    range_size: float,
    undistort: Callable[[np.ndarray], np.ndarray] | None = None,
) -> tuple[FrameSolutions | None, list[str | None]]:
    """Check and solve every detection of a frame.

    Args:
        k: (3, 3) camera intrinsics; image_size: width and height, pixels.
        r_world_cam: (3, 3), t_world_cam: (3,) camera pose from odometry (and the mount).
        range_size: gate size assumed for the range check, m.
        undistort: for a camera with lens distortion, maps its (4, 2) pixels to pinhole pixels
            of ``k`` (the corners are checked as detected, solved undistorted).

    Returns:
        the solutions of the usable detections (None when there are none), and for each detection
        why it was rejected (one of :data:`.pnp.REJECT_REASONS`) or None when it was solved.
    """
    width, height = image_size
    reasons: list[str | None] = []
    slots, costs, distance = [], [], []
    for det in detections:
        reason = check_corners(det.corners, width, height, cfg)
        if reason is None:
            corners = det.corners if undistort is None else undistort(det.corners)
            sols, c = [], None
            if np.isfinite(corners).all():  # undistorted: NaN outside the lens' one-to-one range
                sols, c = measure_candidates(corners, 1.0, k, r_world_cam, t_world_cam, cfg)
            if not sols:
                reason = "pnp_failed"
            else:
                t0 = sols[0].t_cam_gate
                dist = math.sqrt(float(t0 @ t0))
                if dist * range_size > cfg.max_range_m:
                    reason = "range"
        reasons.append(reason)
        if reason is None:
            slots.append((sols[0], sols[-1]))
            costs.append((c[0], c[1] if len(c) == 2 else math.inf))
            distance.append(dist)
    if not slots:
        return None, reasons
    r = np.array([(a.r_cam_gate, b.r_cam_gate) for a, b in slots])
    t = np.array([(a.t_cam_gate, b.t_cam_gate) for a, b in slots])
    cov6 = pose_covariance(k, r[:, 0], t[:, 0], 1.0, cfg.pixel_sigma)
    costs_arr = np.array(costs)
    att = math.radians(cfg.odometry_att_sigma_deg)
    bearing_sigma = np.hypot(cfg.center_sigma_px / np.array([k[0, 0], k[1, 1]]), att)
    frame = FrameSolutions(r, t, costs_arr, np.isfinite(costs_arr[:, 1]), cov6, np.array(distance),
                           bearing_sigma)  # fmt: skip
    return frame, reasons


def measure_frame(
    sol: FrameSolutions,
    size: float,
    r_world_cam: np.ndarray,
    t_world_cam: np.ndarray,
    cfg: MeasurementConfig,
) -> FrameMeasurements:
    """World-frame measurements of a frame's solutions scaled to a gate of ``size``."""
    cov6 = scale_covariance(sol.cov6, size)
    cov = measurement_covariance(cov6, size * sol.distance, r_world_cam, cfg)
    t = sol.t_cam_gate * size
    pos, yaw = world_pose(sol.r_cam_gate, t, r_world_cam, t_world_cam)
    z = np.concatenate([pos, yaw[..., None]], axis=-1)
    return FrameMeasurements(z, cov, np.sqrt(np.sum(t * t, axis=-1)))


def bearing_sq(
    sol: FrameSolutions,
    means: np.ndarray,
    covs: np.ndarray,
    r_world_cam: np.ndarray,
    t_world_cam: np.ndarray,
) -> np.ndarray:
    """Squared Mahalanobis distances of each solution's direction from where each gate's
    estimate projects (χ², 2 dof), in normalised image coordinates; inf for a gate behind the
    camera.

    Args:
        means: (M, 4), covs: (M, 4, 4) gate tracks.

    Returns:
        (D, 2, M) χ² values.
    """
    p = (means[:, :3] - t_world_cam) @ r_world_cam  # (M, 3) camera frame
    z = p[:, 2]
    ahead = z > 1e-3
    zs = np.where(ahead, z, 1.0)
    jac = np.zeros((len(p), 2, 3))  # d(x/z, y/z) / d(camera frame), then / d(world)
    jac[:, 0, 0] = jac[:, 1, 1] = 1.0 / zs
    jac[:, :, 2] = -p[:, :2] / zs[:, None] ** 2
    jac = jac @ r_world_cam.T
    spread = jac @ covs[:, :3, :3] @ np.swapaxes(jac, 1, 2) + np.diag(sol.bearing_sigma**2)
    t = sol.t_cam_gate
    seen = t[..., :2] / t[..., 2:3]  # (D, 2, 2)
    nu = seen[:, :, None, :] - (p[:, :2] / zs[:, None])  # (D, 2, M, 2)
    d2 = np.einsum("dkmi,mij,dkmj->dkm", nu, np.linalg.inv(spread), nu)
    return np.where(ahead, d2, np.inf)


def _track_scores(
    m: FrameMeasurements, gaps: np.ndarray, means: np.ndarray, covs: np.ndarray,
    excluded: np.ndarray,
) -> tuple[np.ndarray, ...]:  # fmt: skip
    """Each (detection, gate) pair's best solution slot: the lowest d² + cost gap.

    Args:
        gaps: (D, 2) each slot's cost minus the best slot's.
        means: (M, 4), covs: (M, 4, 4) gate tracks (of the measurements' size).
        excluded: (D, 2, M) pairs outside the direction or range gates, or below the floor: their
            d² is infinite.

    Returns:
        (D, M) arrays: the score, its d², the slot, and the other slot's score minus the best's.
    """
    d2 = batch_mahalanobis_sq(means, covs, m.z, m.cov)  # (D, 2, M)
    d2 = np.where(excluded, np.inf, d2)
    score = d2 + gaps[..., None]
    slot = np.argmin(score, axis=1)  # (D, M)
    top = np.take_along_axis(score, slot[:, None], axis=1)[:, 0]
    with np.errstate(invalid="ignore"):  # inf - inf where nothing is within the gate
        alt = np.take_along_axis(score, 1 - slot[:, None], axis=1)[:, 0] - top
    return top, np.take_along_axis(d2, slot[:, None], axis=1)[:, 0], slot, alt


def _measurement(
    sol: FrameSolutions, m: FrameMeasurements, d: int, slot: int, gap: float
) -> GateMeasurement:
    """Detection ``d``'s solution ``slot`` as a measurement, its heading variance widened by the
    other solution (``gap``: the other's score minus this one's; :func:`.filter.heading_spread`)."""
    yaws, cov = m.z[d, :, 3].tolist(), m.cov[d].copy()
    if sol.two[d]:
        cov[3, 3] += heading_spread(yaws[slot], yaws[1 - slot], gap)
    distance, cost = float(m.distance[d, slot]), float(sol.costs[d, slot])
    return GateMeasurement(m.z[d, slot, :3].copy(), yaws[slot], cov, distance, cost)


def match_detections(
    sol: FrameSolutions,
    tracks: list[GateTrack],
    new_size: float,
    r_world_cam: np.ndarray,
    t_world_cam: np.ndarray,
    cfg: EstimatorConfig,
    t: float = float("nan"),
) -> tuple[list[tuple[float, int, GateMeasurement]], list[GateMeasurement], int]:
    """Associate the frame's detections with gate tracks, at most one detection per track.

    Both PnP solutions are tried against every track of each gate size (Mahalanobis distance plus
    the solution's cost gap); a pair is allowed when its d² is within the χ² gate, the
    detection does not miss the track's projected direction (``bearing_chi2``) and its range is
    within ``range_ratio`` of the track's (beyond twice the track's spread), and, for a gate of
    the map, it stays within ``map_limit_sigmas`` of where the map put it. Among the
    allowed pairs the one-to-one assignment of lowest total score is taken (two gates stacked on
    one line of sight are seen together; each detection to the gate that explains it best, one
    at a time, would give both to one gate and leave the other unmeasured).

    Args:
        new_size: gate size of a measurement that fits no track, m.
        t: the frame's time, s: a track nearer than ``confirmed_within_m`` and measured within
            ``confirmed_s`` before it allows only ranges within ``confirmed_range_ratio`` of its
            own (NaN: no track counts as measured).

    Returns:
        (score, track index, measurement) of each matched detection, the measurements of the
        detections no track allows (for a gate of ``new_size``; none whose centre is below
        ``MeasurementConfig.min_height_m``), in detection order, and how many detections were
        allowed a track but left without one.
    """
    gaps = sol.costs - sol.costs[:, :1]
    n_det = len(gaps)
    means = np.array([tr.mean for tr in tracks]).reshape(-1, 4)
    covs = np.array([tr.cov for tr in tracks]).reshape(-1, 4, 4)
    track_size = np.array([tr.size for tr in tracks])
    off_bearing = bearing_sq(sol, means, covs, r_world_cam, t_world_cam) > cfg.filter.bearing_chi2
    track_range = np.linalg.norm(means[:, :3] - t_world_cam, axis=1)
    recent = np.array([t - tr.last_hit_t <= cfg.filter.confirmed_s for tr in tracks], bool)
    confirmed = recent & (track_range < cfg.filter.confirmed_within_m)
    track_spread = 2.0 * np.sqrt(np.trace(covs[:, :3, :3], axis1=1, axis2=2))
    anchors = np.array([tr.anchor for tr in tracks]).reshape(-1, 3)
    from_map = np.array([tr.from_map for tr in tracks], bool)  # map-free gates: no map to keep to
    limit = np.where(from_map, cfg.map_limit_m, np.inf)
    ratio = cfg.filter.range_ratio
    tight = cfg.filter.confirmed_range_ratio
    score = np.full((n_det, len(tracks)), np.inf)
    slot = np.zeros((n_det, len(tracks)), int)
    alt = np.full((n_det, len(tracks)), np.inf)
    measured: dict[float, FrameMeasurements] = {}
    for size in sorted(set(track_size.tolist())):
        idx = np.flatnonzero(track_size == size)
        m = measured[size] = measure_frame(sol, size, r_world_cam, t_world_cam, cfg.measurement)
        seen = m.distance[..., None]  # (D, 2, 1) against (M,)
        off_range = (seen > ratio * (track_range[idx] + track_spread[idx])) | (
            seen * ratio < track_range[idx] - track_spread[idx]
        )
        off_range |= confirmed[idx] & (
            (seen > tight * track_range[idx]) | (seen * tight < track_range[idx])
        )
        off_map = np.linalg.norm(m.z[:, :, None, :3] - anchors[idx], axis=-1) > limit[idx]
        below_floor = (m.z[:, :, 2] < cfg.measurement.min_height_m)[..., None]
        excluded = off_bearing[:, :, idx] | off_range | off_map | below_floor
        top, d2, slot[:, idx], alt[:, idx] = _track_scores(m, gaps, means[idx], covs[idx], excluded)
        score[:, idx] = np.where(d2 <= cfg.filter.gate_chi2, top, np.inf)
    allowed = np.isfinite(score)
    pairs = []
    if allowed.any():
        rows, cols = linear_sum_assignment(np.where(allowed, score, _NOT_ALLOWED))
        for d, ti in zip(rows.tolist(), cols.tolist(), strict=True):
            if allowed[d, ti]:
                m = measured[float(track_size[ti])]
                z = _measurement(sol, m, d, int(slot[d, ti]), float(alt[d, ti]))
                pairs.append((float(score[d, ti]), ti, z))
    unmatched = []
    for d in np.flatnonzero(~allowed.any(axis=1)).tolist():
        if new_size not in measured:
            measured[new_size] = measure_frame(
                sol, new_size, r_world_cam, t_world_cam, cfg.measurement
            )
        if measured[new_size].z[d, 0, 2] >= cfg.measurement.min_height_m:
            unmatched.append(_measurement(sol, measured[new_size], d, 0, float(gaps[d, 1])))
    return pairs, unmatched, int(allowed.any(axis=1).sum()) - len(pairs)
