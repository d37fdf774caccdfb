"""The detector's error model: how far off, and how often missing, it is at each distance.

Written by ``eval-detector`` and read by the policy trainer
(:class:`icarus_vision.policy.perception_noise.ErrorModel`) to inject realistic perception noise.
Format (JSON)::

    {"distance_m": [bin centres, increasing], "sigma_m": [...], "miss_rate": [...], ...}

``sigma_m`` is the per-axis standard deviation of the error of the gate *centre* position that PnP
recovers from the detected corners, in metres: for each detected gate, PnP (``SOLVEPNP_IPPE_SQUARE``)
is solved once from the detected and once from the true corners, with the same square; the
difference of the two centres, scaled by (true distance / distance from the true corners), is the
error (3-vector, camera frame). Per bin, sigma = RMS over the three axes after dropping the worst
2 % (PnP flips); a bin with fewer than three detections takes ``a d^2`` fitted to all
detections (the pinhole propagation of a constant pixel error; ``a = 1`` with none). ``miss_rate`` is the fraction of gates not matched (gates with all four corners in
the image and at least three visible, any size). Extra fields: the camera-frame per-axis sigmas, the
corner pixel error spread per bin, and the same figures by viewing angle (angle between the line of
sight and the gate's passage axis).
"""

from __future__ import annotations

import math

import cv2
import numpy as np

DISTANCE_EDGES_M = (0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 8.0, 10.0, 12.0, 15.0, 20.0, 30.0, math.inf)
"""Bin edges of the error model, m (bins with fewer than ``MIN_GATES`` gates are merged away)."""
ANGLE_EDGES_DEG = (0.0, 15.0, 30.0, 45.0, 60.0, 90.0)
"""Viewing-angle bin edges, degrees."""
MIN_GATES = 8
"""Fewest gates a bin needs to be reported."""


def pnp_centre(corners: np.ndarray, k: np.ndarray, size: float = 1.0) -> np.ndarray | None:
    """Gate centre in the camera frame from its four corners (TL, TR, BR, BL), or None.

    Args:
        corners: (4, 2) pixels.
        k: (3, 3) intrinsics.
        size: side of the square opening, m.
    """
    s = size / 2.0
    obj = np.array([[-s, s, 0.0], [s, s, 0.0], [s, -s, 0.0], [-s, -s, 0.0]])
    img = np.ascontiguousarray(corners, dtype=np.float64).reshape(4, 1, 2)
    try:
        ok, _, t = cv2.solvePnP(
            obj, img, np.asarray(k, float), None, flags=cv2.SOLVEPNP_IPPE_SQUARE
        )
    except cv2.error:
        return None
    if not ok or t is None:
        return None
    t = np.asarray(t, float).reshape(3)
    return t if np.all(np.isfinite(t)) and t[2] > 0 else None


def gate_error(
    pred: np.ndarray, truth: np.ndarray, k: np.ndarray, distance: float
) -> np.ndarray | None:
    """(3,) camera-frame centre error of a detection (see the module docstring), m, or None."""
    t_true, t_pred = pnp_centre(truth, k), pnp_centre(pred, k)
    if t_true is None or t_pred is None:
        return None
    return (t_pred - t_true) * (distance / np.linalg.norm(t_true))


def _rms(errs: list[np.ndarray]) -> tuple[float, list[float]]:
    e = np.array(errs, float).reshape(-1, 3)
    norm = np.linalg.norm(e, axis=1)
    e = e[norm <= np.percentile(norm, 98)] if len(e) >= 10 else e
    return float(np.sqrt(np.mean(e**2))), [float(np.sqrt(np.mean(e[:, i] ** 2))) for i in range(3)]


def _bins(values: np.ndarray, edges: tuple[float, ...]) -> list[np.ndarray]:
    """Index arrays of the samples in each bin, merging bins with fewer than MIN_GATES into the next."""
    out, pending = [], np.zeros(0, int)
    for lo, hi in zip(edges[:-1], edges[1:], strict=True):
        idx = np.concatenate([pending, np.flatnonzero((values >= lo) & (values < hi))])
        if len(idx) >= MIN_GATES:
            out.append(idx)
            pending = np.zeros(0, int)
        else:
            pending = idx
    if len(pending) and out:
        out[-1] = np.concatenate([out[-1], pending])
    elif len(pending):
        out.append(pending)
    return out


def _quadratic_coefficient(samples: list[dict]) -> float:
    """a in sigma(d) = a d^2, fitted to every PnP error (1.0 when there is none)."""
    pairs = [(s["error"], s["distance"]) for s in samples if s["error"] is not None]
    if not pairs:
        return 1.0
    return float(np.sqrt(np.median([np.sum(e**2) / 3.0 / d**4 for e, d in pairs])))


def _table(samples: list[dict], key: str, edges: tuple[float, ...]) -> dict:
    values = np.array([s[key] for s in samples], float)
    rows = {
        key: [],
        "sigma_m": [],
        "sigma_xyz_m": [],
        "miss_rate": [],
        "corner_px": [],
        "gates": [],
    }
    a = _quadratic_coefficient(samples)
    for idx in _bins(values, edges):
        group = [samples[i] for i in idx]
        errs = [s["error"] for s in group if s["error"] is not None]
        px = np.concatenate([s["corner_px"] for s in group if s["corner_px"] is not None] or [[]])
        if len(errs) >= 3:
            sigma, xyz = _rms(errs)
        else:  # (almost) all missed: the global fit sigma = a d^2 (pinhole error propagation)
            sigma = a * float(values[idx].mean()) ** 2
            xyz = [sigma] * 3
        rows[key].append(round(float(values[idx].mean()), 4))
        rows["sigma_m"].append(round(sigma, 5))
        rows["sigma_xyz_m"].append([round(x, 5) for x in xyz])
        rows["miss_rate"].append(round(1.0 - sum(s["matched"] for s in group) / len(group), 5))
        rows["corner_px"].append(
            {"rms": round(float(np.sqrt(np.mean(px**2))), 4) if len(px) else None,
             "median": round(float(np.median(px)), 4) if len(px) else None}
        )  # fmt: skip
        rows["gates"].append(len(group))
    return rows


def build_error_model(samples: list[dict], detector: str) -> dict:
    """The error model of a detector from per-gate samples.

    Args:
        samples: per gate, ``distance`` m, ``angle_deg`` viewing angle, ``matched`` bool,
            ``error`` (3,) m or None (see :func:`gate_error`), ``corner_px`` (4,) or None.
        detector: the detector spec (recorded).

    Returns:
        the JSON-ready dict (``distance_m``, ``sigma_m``, ``miss_rate`` + extras).

    Raises:
        ValueError: no samples.
    """
    if not samples:
        raise ValueError("no gates to build an error model from")
    by_dist = _table(samples, "distance", DISTANCE_EDGES_M)
    by_angle = _table(samples, "angle_deg", ANGLE_EDGES_DEG)
    return {
        "format": "icarus-vision-error-model/1",
        "detector": detector,
        "distance_m": by_dist.pop("distance"),
        "sigma_m": by_dist.pop("sigma_m"),
        "miss_rate": by_dist.pop("miss_rate"),
        **by_dist,
        "by_angle": {"angle_deg": by_angle.pop("angle_deg"), **by_angle},
        "notes": "sigma_m: per-axis std of the PnP gate-centre error (camera frame); "
        "miss_rate: unmatched fraction of gates fully in view with >= 3 visible corners",
    }


def viewing_angle_deg(r_cam_gate: np.ndarray, t_cam_gate: np.ndarray) -> float:
    """Angle between the line of sight to the gate and its passage axis, degrees (0 = head-on)."""
    axis = np.asarray(r_cam_gate, float)[:, 0]
    t = np.asarray(t_cam_gate, float)
    c = abs(float(axis @ t) / max(np.linalg.norm(t), 1e-9))
    return math.degrees(math.acos(min(c, 1.0)))
