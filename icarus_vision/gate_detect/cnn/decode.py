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

import functools
import itertools
from dataclasses import dataclass

import cv2
import numpy as np
import torch

from icarus_vision.gate_detect.cnn.model import VECTOR_SCALE
from icarus_vision.gate_detect.metrics import mean_sides


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
    max_outside_px: float | None = 1.5
    """A gate is reported only if each of its corners lies in the image (which spans -0.5 to
    W - 0.5 px) or at most this far outside it (:func:`in_frame`). A gate cut by the frame's
    edge has corners no camera saw: the network extrapolates them, often wrongly, the estimator
    cannot use them (``MeasurementConfig.image_margin_px``) and eval-detector counts no such
    gate. None: no check. Candidates for the refiner are not checked (it may move their corners
    into the image); the detector checks its final corners."""


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


def peak_maps(heat: np.ndarray, thresholds: np.ndarray) -> tuple[np.ndarray, ...]:
    """Local maxima (3x3) of (K, H, W) probability maps at or above (K,) ``thresholds``: indices
    (k, y, x), sorted by map, then row, then column.

    The maps are dilated in one call, stacked with a row of -inf between them (so no maximum
    sees across from the next map; the image border also counts as -inf)."""
    k, h, w = heat.shape
    stacked = np.full((k, h + 1, w), -np.inf, np.float32)
    stacked[:, :h] = heat
    dilated = cv2.dilate(stacked.reshape(k * (h + 1), w), _KERNEL).reshape(k, h + 1, w)
    return np.nonzero((stacked == dilated) & (stacked >= thresholds[:, None, None]))


def nested_gates(
    centres: np.ndarray,
    vectors: np.ndarray,
    peaks: tuple[np.ndarray, np.ndarray, np.ndarray],
    max_residual: float = DecodeConfig.nested_residual,
) -> list[list[tuple[np.ndarray, np.ndarray]]]:
    """Other gates around centre peaks: corner peaks shaped like each regressed gate.

    For each centre, every choice of one peak (or none) per corner type, with at least three
    peaks, is fitted to the regressed shape by a similarity transform (scale, rotation, shift;
    least squares). A choice is a gate when the fit is close (``max_residual``), barely rotated,
    at another scale within ``NESTED_SCALE`` and centred near the peak; a missing corner comes
    from the fit. All centres are searched together (a few numpy calls per frame, not per centre).

    Args:
        centres: (P, 2) centre cells.
        vectors: (P, 4, 2) regressed centre-to-corner vectors, cells.
        peaks: every corner peak: positions (N,) complex x + iy, cells; types (N,) int 0-3;
            scores (N,).
        max_residual: largest RMS misfit of the corners to the regressed shape, relative to
            the gate's size.

    Returns:
        per centre, its gates ``(corners (4, 2) cells, scores (4,): 0 for a fitted corner)``, in
        the order of the choices (the first corner type's peak varying slowest).
    """
    z, kind, val = peaks
    found: list[list[tuple[np.ndarray, np.ndarray]]] = [[] for _ in range(len(centres))]
    if not len(centres) or len(z) < NESTED_MIN_CORNERS:
        return found
    tmpl = vectors[..., 0] + 1j * vectors[..., 1]  # (P, 4) the regressed shapes about the centre
    side = mean_sides(vectors)
    c0 = centres[:, 0] + 1j * centres[:, 1]
    with np.errstate(divide="ignore", invalid="ignore"):
        w = (z - c0[:, None]) / tmpl[:, kind]  # (P, N) real: scale along the corner's direction
        tan = np.abs(w.imag) / w.real
    near = (w.real > NESTED_SCALE[0]) & (w.real < NESTED_SCALE[1]) & (tan < NESTED_SECTOR_TAN)
    # per centre, its peaks by type (peaks not near it last), then nearest the direction first
    k = np.where(near, kind, 4)
    order = np.lexsort((tan, k), axis=-1)
    rows = np.arange(len(centres))[:, None]
    k = k[rows, order]
    per_type = (k[:, :, None] == np.arange(5)).sum(axis=1)  # (P, 5)
    start = np.cumsum(per_type, axis=1) - per_type
    rank = np.arange(len(z)) - start[rows, k]  # position within its type
    r, i = np.nonzero((k < 4) & (rank < MAX_PEAKS_PER_TYPE))
    j, rank = order[r, i], rank[r, i] + 1
    counts = np.minimum(per_type[:, :4], MAX_PEAKS_PER_TYPE)  # (P, 4) peaks tried per type
    pts = np.full((len(centres), 4, MAX_PEAKS_PER_TYPE + 1), np.nan + 0j)  # column 0: "no peak"
    vals = np.zeros((len(centres), 4, MAX_PEAKS_PER_TYPE + 1))
    pts[r, kind[j], rank], vals[r, kind[j], rank] = z[j], val[j]
    choices, peaks_in = _choices(tuple((counts.max(axis=0) + 1).tolist()))
    usable = (side >= 1e-3) & (np.count_nonzero(counts, axis=1) >= NESTED_MIN_CORNERS)
    keep = (
        usable[:, None]
        & (choices[None] <= counts[:, None]).all(axis=2)
        & (peaks_in >= NESTED_MIN_CORNERS)
    )
    p, c = np.nonzero(keep)  # (centre, choice) pairs, by centre then choice
    choice = choices[c]  # (K, 4)
    q, have = pts[p[:, None], np.arange(4), choice], choice > 0  # (K, 4) complex peaks
    tmpl, c0, side = tmpl[p], c0[p], side[p]
    n = have.sum(axis=1)
    p_mean = (tmpl * have).sum(axis=1) / n
    q_mean = np.where(have, q, 0).sum(axis=1) / n
    dp = np.where(have, tmpl - p_mean[:, None], 0)
    dq = np.where(have, q - q_mean[:, None], 0)
    a = (np.conj(dp) * dq).sum(axis=1) / (np.abs(dp) ** 2).sum(axis=1)  # scale * e^(i turn)
    fit = a[:, None] * (tmpl - p_mean[:, None]) + q_mean[:, None]  # (K, 4)
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
    corners = np.where(have[ok], q[ok], fit[ok])  # (G, 4) complex corners, fitted where missing
    corners = np.stack([corners.real, corners.imag], axis=2)
    scores = vals[p[ok][:, None], np.arange(4), choice[ok]]
    for i, g, s in zip(p[ok].tolist(), corners, scores, strict=True):
        found[i].append((g, s))
    return found


@functools.cache
def _choices(shape: tuple[int, ...]) -> tuple[np.ndarray, np.ndarray]:
    """(M, 4) every choice of a peak (1, 2, ...) or none (0) per corner type, below ``shape``
    per type, in C order (the first type varying slowest); (M,) the peaks each chooses."""
    choices = np.indices(shape).reshape(len(shape), -1).T
    return choices, (choices > 0).sum(axis=1)


def snap(
    regressed: np.ndarray, peaks: tuple[np.ndarray, np.ndarray, np.ndarray], snap_radius: float
) -> tuple[np.ndarray, np.ndarray]:
    """Move each corner of (N, 4, 2) regressed gates to the nearest peak of its type within the
    snap radius (``snap_radius`` of the gate's mean side, at least 1.5 cells).

    Args:
        peaks: every corner peak: positions (M, 2) cells, types (M,) int 0-3, scores (M,).

    Returns:
        (corners (N, 4, 2), scores (N, 4): the peak's score, 0 where nothing was near).
    """
    pos, kind, val = peaks
    if not len(pos) or not len(regressed):
        return regressed.copy(), np.zeros(regressed.shape[:2])
    radius = np.maximum(1.5, snap_radius * mean_sides(regressed))
    d = np.sqrt(((pos - regressed[:, :, None]) ** 2).sum(axis=3))  # (N, 4, M)
    d[:, kind[None] != np.arange(4)[:, None]] = np.inf  # peaks of another type
    j = d.argmin(axis=2)
    near = np.take_along_axis(d, j[..., None], axis=2)[..., 0] <= radius[:, None]
    corners = np.where(near[..., None], pos[j], regressed)
    return corners, np.where(near, val[j], 0.0)


def decode(
    out: np.ndarray | torch.Tensor,
    cfg: DecodeConfig,
    scale: tuple[float, float],
    with_peaks: bool = False,
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
        score of its corners. Only gates :func:`in_frame`, unless ``with_peaks``: then the
        candidates for the refiner, and a pair ``(gates, peaks)``, peaks being per corner type
        ``(positions (M, 2) pixels, scores (M,))``.
    """
    if isinstance(out, torch.Tensor):
        out = out.detach().numpy()
    maps = np.ascontiguousarray(out, dtype=np.float32)
    heat, reg = 1.0 / (1.0 + np.exp(-maps[:5])), maps[5:]
    thresholds = np.array([cfg.centre_threshold] + [cfg.corner_threshold] * 4, np.float32)
    ks, ys, xs = peak_maps(heat, thresholds)
    ends = np.searchsorted(ks, np.arange(6)).tolist()  # peaks of map k: ends[k]:ends[k + 1]
    # centre peaks, best first, with the corners they regress
    cys, cxs = ys[: ends[1]], xs[: ends[1]]
    order = np.argsort(-heat[0, cys, cxs])[: cfg.max_gates]
    cys, cxs = cys[order], cxs[order]
    centres = np.stack([cxs, cys], axis=1).astype(float)
    vectors = VECTOR_SCALE * reg[2:, cys, cxs].T.reshape(-1, 4, 2)
    # corner peaks, each at its regressed sub-cell position
    ks, ys, xs = ks[ends[1] :], ys[ends[1] :], xs[ends[1] :]
    peaks = (np.stack([xs + reg[0, ys, xs], ys + reg[1, ys, xs]], axis=1), ks - 1, heat[ks, ys, xs])
    found = _hypotheses(centres, vectors, heat[0, cys, cxs].tolist(), peaks, cfg)
    gates = _best(found, scale, cfg)
    if not with_peaks:
        size = (scale[0] * out.shape[-1], scale[1] * out.shape[-2])
        return in_frame(gates, size, cfg.max_outside_px)
    pos, _, val = peaks
    per_type = itertools.pairwise([e - ends[1] for e in ends[1:]])
    return gates, [(pos[a:b] * np.asarray(scale) - 0.5, val[a:b]) for a, b in per_type]


def _hypotheses(
    centres: np.ndarray,
    vectors: np.ndarray,
    scores: list[float],
    peaks: tuple[np.ndarray, np.ndarray, np.ndarray],
    cfg: DecodeConfig,
) -> list[tuple[np.ndarray, np.ndarray, float]]:
    """Each centre peak's regressed gate (corners snapped), then, unless a better one overlaps it
    (the same gate), the gates nested in or around it: ``(corners (4, 2) cells, corner scores
    (4,), score)`` in that order.

    Args:
        centres: (P, 2) centre peaks, cells, best first.
        vectors: (P, 4, 2) their regressed centre-to-corner vectors, cells.
        scores: (P,) their heatmap values.
        peaks: corner peaks: positions (M, 2) cells, types (M,) 0-3, scores (M,).
    """
    snapped, snapped_scores = snap(centres[:, None] + vectors, peaks, cfg.snap_radius)
    # a weaker peak of a gate already searched around is not searched again
    primary: list[bool] = []
    box = boxes(snapped)
    for i, g in enumerate(snapped):
        primary.append(not any(quad_iou(g, snapped[j]) > cfg.nms_iou for j in range(i)
                               if primary[j] and not apart(box[i], box[j])))  # fmt: skip
    nested = iter(())
    if cfg.nested:
        pos, kind, val = peaks
        keep = np.array(primary, bool)
        z = pos[:, 0] + 1j * pos[:, 1]
        nested = iter(
            nested_gates(centres[keep], vectors[keep], (z, kind, val), cfg.nested_residual)
        )
    found = []
    for g, s, score, is_primary in zip(snapped, snapped_scores, scores, primary, strict=True):
        found.append((g, s, score))
        if is_primary and cfg.nested:
            found += [(g, s, score * float(s.mean())) for g, s in next(nested)]
    return found


def _best(
    found: list[tuple[np.ndarray, np.ndarray, float]],
    scale: tuple[float, float],
    cfg: DecodeConfig,
) -> list[tuple[np.ndarray, np.ndarray, float]]:
    """The gates among hypotheses (:func:`_hypotheses`), in camera pixels: best score first,
    confirmed by their corners (``min_snapped``) or sure (``sure_centre``), none overlapping a
    better one by more than ``nms_iou``, at most ``max_gates``."""
    found = sorted(found, key=lambda f: -f[2])
    pixels = np.array([g for g, _, _ in found]).reshape(-1, 4, 2) * np.asarray(scale) - 0.5
    box = boxes(pixels)
    gates, kept = [], []
    for i, (corners, (_, s, score)) in enumerate(zip(pixels, found, strict=True)):
        if np.count_nonzero(s) < cfg.min_snapped and score < cfg.sure_centre:
            continue
        if any(quad_iou(corners, pixels[j]) > cfg.nms_iou
               for j in kept if not apart(box[i], box[j])):  # fmt: skip
            continue
        gates.append((corners, s, score))
        kept.append(i)
        if len(gates) == cfg.max_gates:
            break
    return gates


def in_frame(
    found: list[tuple[np.ndarray, np.ndarray, float]],
    image_size: tuple[int, int],
    max_outside_px: float | None,
) -> list[tuple[np.ndarray, np.ndarray, float]]:
    """The gates of ``found`` (``(corners (4, 2) px, corner_scores, score)``) whose corners all
    lie within ``max_outside_px`` of a (W, H) image (``DecodeConfig.max_outside_px``; None: all
    of them)."""
    if not found or max_outside_px is None:
        return found
    w, h = image_size
    q = np.stack([c for c, _, _ in found])
    lo, hi = -0.5 - max_outside_px, np.array([w, h]) - 0.5 + max_outside_px
    ok = ((q >= lo) & (q <= hi)).all(axis=(1, 2))
    return [f for f, keep in zip(found, ok, strict=True) if keep]


def quad_iou(a: np.ndarray, b: np.ndarray) -> float:
    """Intersection over union of two (4, 2) quadrilaterals (their convex hulls), in [0, 1]."""
    ha = cv2.convexHull(np.asarray(a, np.float32))
    hb = cv2.convexHull(np.asarray(b, np.float32))
    inter, _ = cv2.intersectConvexConvex(ha, hb)
    union = cv2.contourArea(ha) + cv2.contourArea(hb) - inter
    return min(float(inter / union), 1.0) if union > 0 else 0.0


def boxes(quads: np.ndarray) -> list[tuple[float, float, float, float]]:
    """Bounding boxes (x0, y0, x1, y1) of (N, 4, 2) quadrilaterals, as Python floats (for
    :func:`apart`)."""
    q = np.asarray(quads, float).reshape(-1, 4, 2)
    return [tuple(b) for b in np.concatenate([q.min(axis=1), q.max(axis=1)], axis=1).tolist()]


def apart(a: tuple[float, ...], b: tuple[float, ...]) -> bool:
    """Whether two :func:`boxes` do not overlap: then so do their quadrilaterals, and
    :func:`quad_iou` is 0 (checking this first saves most of its calls)."""
    return a[2] < b[0] or b[2] < a[0] or a[3] < b[1] or b[3] < a[1]
