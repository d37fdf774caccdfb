"""Decoding the corner network's maps into gate detections.

Each centre peak regresses its gate's four corners; each is then snapped to the nearest peak of the
same corner type's heatmap, which is more precise. On a racing line the next gates are often seen
through the opening of the nearest one, all with nearly the same centre, and a centre peak can
regress only one of them. So each centre peak also looks for corner peaks, three or four of them,
shaped like its regressed gate at another scale: each such set is one more gate hypothesis (a
gate nested in, or around, the regressed one). Duplicates are removed by overlap at the end.

Grid units throughout (cells of the output map); ``decode`` converts to camera pixels at the end.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
import torch

from icarus_vision.gate_detect.cnn.model import VECTOR_SCALE
from icarus_vision.gate_detect.metrics import mean_side


@dataclass(frozen=True)
class DecodeConfig:
    """Thresholds that turn the network's maps into detections (stored with the weights)."""

    centre_threshold: float = 0.3
    """Smallest centre-heatmap peak reported as a gate."""
    corner_threshold: float = 0.1
    """Smallest corner-heatmap peak a regressed corner may snap to."""
    snap_radius: float = 0.3
    """Snap radius as a fraction of the regressed opening's mean side (at least 1.5 cells)."""
    max_gates: int = 20
    """Most gates reported per image."""
    min_snapped: int = 0
    """Fewest corners that must have snapped to a corner peak for a gate to be reported (a centre
    peak whose corners the corner maps do not confirm is usually a false alarm), unless its score
    is at least ``sure_centre``."""
    sure_centre: float = 1.0
    """A gate scored at least this is reported however few of its corners snapped (1: never)."""
    nms_iou: float = 0.5
    """A gate whose opening overlaps a better-scored one's by more than this (intersection over
    union) is the same gate found twice, and dropped."""
    nested: bool = True
    """Look for gates nested in (or around) each regressed one (module docstring)."""
    nested_residual: float = 0.05
    """Largest RMS misfit of a nested gate's corners to the regressed shape, relative to its size."""


NESTED_SCALE = (0.15, 6.0)
"""Scales, relative to the regressed gate, searched for nested gates."""
NESTED_MAX_TURN = np.radians(12.0)
"""Largest in-image rotation of a nested gate relative to the regressed one, radians."""
NESTED_MAX_OFFSET = 0.3
"""Largest distance from the centre peak to a nested gate's centre, relative to its mean side."""
NESTED_MIN_CORNERS = 3
"""Corner peaks (of four) that a nested gate needs."""
NESTED_SECTOR_TAN = 0.6
"""Corner peaks tried for a nested gate lie within atan(0.6) = 31 degrees of the regressed corner's
direction from the centre (wider than ``NESTED_MAX_TURN``: the centres of nested gates differ)."""
MAX_PEAKS_PER_TYPE = 4
"""Corner peaks of each type (those nearest the regressed direction) tried for nested gates."""

_KERNEL = np.ones((3, 3), np.uint8)


def _peaks(heat: np.ndarray, threshold: float) -> np.ndarray:
    """(H, W) probabilities -> boolean local maxima (3x3) at or above ``threshold``."""
    return (heat == cv2.dilate(heat, _KERNEL)) & (heat >= threshold)


def nested_gates(
    centre: np.ndarray,
    vectors: np.ndarray,
    peaks: tuple[np.ndarray, np.ndarray, np.ndarray],
    max_residual: float = DecodeConfig.nested_residual,
) -> list[tuple[np.ndarray, np.ndarray]]:
    """Other gates around one centre peak: corner peaks shaped like the regressed gate.

    Every choice of one peak (or none) per corner type, with at least three peaks, is fitted to
    the regressed shape by a similarity transform (scale, rotation, shift; least squares). A
    choice is a gate when the fit is close (``max_residual``), barely rotated, at another
    scale within ``NESTED_SCALE`` and centred near the peak; a missing corner comes from the fit.

    Args:
        centre: (2,) centre cell.
        vectors: (4, 2) regressed centre-to-corner vectors, cells.
        peaks: every corner peak: positions (N,) complex x + iy, cells; types (N,) int 0-3;
            scores (N,).
        max_residual: largest RMS misfit of the corners to the regressed shape, relative to
            the gate's size.

    Returns:
        per gate ``(corners (4, 2) cells, scores (4,): 0 for a fitted corner)``.
    """
    tmpl = vectors[:, 0] + 1j * vectors[:, 1]  # (4,) the regressed shape about the centre
    side = mean_side(vectors)
    z, kind, val = peaks
    if side < 1e-3 or len(z) < NESTED_MIN_CORNERS:
        return []
    c0 = centre[0] + 1j * centre[1]
    with np.errstate(divide="ignore", invalid="ignore"):
        w = (z - c0) / tmpl[kind]  # real: scale along the regressed corner's direction
        tan = np.abs(w.imag) / w.real
    sel = np.flatnonzero(
        (w.real > NESTED_SCALE[0]) & (w.real < NESTED_SCALE[1]) & (tan < NESTED_SECTOR_TAN)
    )
    sel = sel[np.lexsort((tan[sel], kind[sel]))]  # by type, then nearest the direction first
    k = kind[sel]
    rank = np.arange(len(sel)) - np.searchsorted(k, k)  # position within its type
    sel, k, rank = (
        sel[rank < MAX_PEAKS_PER_TYPE],
        k[rank < MAX_PEAKS_PER_TYPE],
        rank[rank < MAX_PEAKS_PER_TYPE],
    )
    counts = np.bincount(k, minlength=4)
    if np.count_nonzero(counts) < NESTED_MIN_CORNERS:
        return []
    pts = np.full((4, MAX_PEAKS_PER_TYPE + 1), np.nan + 0j)  # column 0: "no peak"
    vals = np.zeros((4, MAX_PEAKS_PER_TYPE + 1))
    pts[k, rank + 1], vals[k, rank + 1] = z[sel], val[sel]
    idx = np.indices(tuple(counts + 1)).reshape(4, -1).T  # (M, 4) choices
    q = pts[np.arange(4), idx]  # (M, 4) complex peaks
    have = ~np.isnan(q)
    keep = have.sum(axis=1) >= NESTED_MIN_CORNERS
    q, have, idx = q[keep], have[keep], idx[keep]
    n = have.sum(axis=1)
    p_mean = (tmpl * have).sum(axis=1) / n
    q_mean = np.where(have, q, 0).sum(axis=1) / n
    dp = np.where(have, tmpl - p_mean[:, None], 0)
    dq = np.where(have, q - q_mean[:, None], 0)
    a = (np.conj(dp) * dq).sum(axis=1) / (np.abs(dp) ** 2).sum(axis=1)  # scale * e^(i turn)
    fit = a[:, None] * (tmpl - p_mean[:, None]) + q_mean[:, None]  # (M, 4)
    scale = np.maximum(np.abs(a), 1e-9)
    resid = np.sqrt((np.where(have, np.abs(fit - q), 0) ** 2).sum(axis=1) / n) / (scale * side)
    offset = np.abs(fit.mean(axis=1) - c0) / (scale * side)
    ok = (
        (resid < max_residual)
        & (np.abs(np.angle(a)) < NESTED_MAX_TURN)
        & (scale > NESTED_SCALE[0])
        & (scale < NESTED_SCALE[1])
        & (offset < NESTED_MAX_OFFSET)
    )
    c = np.where(have[ok], q[ok], fit[ok])  # (K, 4) complex corners, fitted where missing
    corners = np.stack([c.real, c.imag], axis=2)
    return list(zip(corners, vals[np.arange(4), idx[ok]], strict=True))


def _snap(
    g: np.ndarray, cand: list[tuple[np.ndarray, np.ndarray]], snap_radius: float
) -> tuple[np.ndarray, np.ndarray]:
    """Move each corner of ``g`` (4, 2) to the nearest peak of its type within the snap radius.

    Returns:
        (corners (4, 2), scores (4,): the peak's score, 0 where nothing was near).
    """
    g = g.copy()
    radius = max(1.5, snap_radius * mean_side(g))
    scores = np.zeros(4)
    for k, (pos, val) in enumerate(cand):
        if len(pos):
            d = np.linalg.norm(pos - g[k], axis=1)
            j = int(np.argmin(d))
            if d[j] <= radius:
                g[k], scores[k] = pos[j], val[j]
    return g, scores


def decode(
    out: torch.Tensor, cfg: DecodeConfig, scale: tuple[float, float], with_peaks: bool = False
):
    """Gates from one image's network output.

    Args:
        out: (15, H, W) raw network output.
        cfg: thresholds.
        scale: (sx, sy) camera pixels per grid cell.
        with_peaks: also return the corner peaks (what the refiner snaps to).

    Returns:
        per gate ``(corners (4, 2) pixels TL, TR, BR, BL, corner_scores (4,), score)``, best first.
        A regressed gate's score is its centre peak's; a nested one's is that times the mean
        score of its corners. With ``with_peaks``, a pair ``(gates, peaks)``, peaks being per
        corner type ``(positions (M, 2) pixels, scores (M,))``.
    """
    maps = np.ascontiguousarray(out.detach().numpy(), dtype=np.float32)
    heat_np, reg = 1.0 / (1.0 + np.exp(-maps[:5])), maps[5:]
    cys, cxs = np.nonzero(_peaks(heat_np[0], cfg.centre_threshold))
    order = np.argsort(-heat_np[0, cys, cxs])[: cfg.max_gates]
    cand = []
    for k in range(4):
        ys, xs = np.nonzero(_peaks(heat_np[1 + k], cfg.corner_threshold))
        pos = np.stack([xs + reg[0, ys, xs], ys + reg[1, ys, xs]], axis=1)
        cand.append((pos, heat_np[1 + k, ys, xs]))
    peaks = (
        np.concatenate([p[:, 0] + 1j * p[:, 1] for p, _ in cand]),
        np.concatenate([np.full(len(p), k) for k, (p, _) in enumerate(cand)]),
        np.concatenate([v for _, v in cand]),
    )
    found, primaries = [], []
    for i in order:
        centre = np.array([cxs[i], cys[i]], float)
        vectors = VECTOR_SCALE * reg[2:, cys[i], cxs[i]].reshape(4, 2)
        score = float(heat_np[0, cys[i], cxs[i]])
        g, scores = _snap(centre + vectors, cand, cfg.snap_radius)
        found.append((g, scores, score))
        if any(quad_iou(g, p) > cfg.nms_iou for p in primaries):
            continue  # a weaker peak of a gate already searched around
        primaries.append(g)
        nested = nested_gates(centre, vectors, peaks, cfg.nested_residual) if cfg.nested else ()
        for g, scores in nested:
            found.append((g, scores, score * float(scores.mean())))
    found.sort(key=lambda f: -f[2])
    gates = []
    for g, scores, score in found:
        if np.count_nonzero(scores) < cfg.min_snapped and score < cfg.sure_centre:
            continue
        corners = g * np.asarray(scale) - 0.5
        if any(quad_iou(corners, c) > cfg.nms_iou for c, _, _ in gates):
            continue
        gates.append((corners, scores, score))
        if len(gates) == cfg.max_gates:
            break
    if with_peaks:
        return gates, [(p * np.asarray(scale) - 0.5, v) for p, v in cand]
    return gates


def quad_iou(a: np.ndarray, b: np.ndarray) -> float:
    """Intersection over union of two (4, 2) quadrilaterals (their convex hulls), in [0, 1]."""
    ha = cv2.convexHull(np.asarray(a, np.float32))
    hb = cv2.convexHull(np.asarray(b, np.float32))
    inter, _ = cv2.intersectConvexConvex(ha, hb)
    union = cv2.contourArea(ha) + cv2.contourArea(hb) - inter
    return min(float(inter / union), 1.0) if union > 0 else 0.0
