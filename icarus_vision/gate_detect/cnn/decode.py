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

import itertools
from dataclasses import dataclass

import numpy as np
import torch
from numba import njit

from icarus_vision.gate_detect.cnn.model import VECTOR_SCALE
from icarus_vision.gate_detect.cnn.polygon import mean_side, quad_iou_kernel


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

MAX_CHOICES = (MAX_PEAKS_PER_TYPE + 1) ** 4
"""Most nested-gate hypotheses one centre peak can yield (a peak or none per corner type)."""


def peak_maps(heat: np.ndarray, thresholds: np.ndarray) -> tuple[np.ndarray, ...]:
    """Local maxima (3x3) of (K, H, W) maps (probabilities, or logits: the decoder's) at or
    above (K,) ``thresholds``: indices (k, y, x), sorted by map, then row, then column. A value
    counts as a maximum if no neighbour in its own map is larger (the border counts as -inf)."""
    return _peaks(np.ascontiguousarray(heat, np.float32), np.asarray(thresholds, np.float32))


@njit(cache=True)
def _peaks(heat: np.ndarray, thresholds: np.ndarray) -> tuple[np.ndarray, ...]:
    k, h, w = heat.shape
    found = np.empty((3, k * h * w), np.int64)
    n = 0
    for c in range(k):
        for y in range(h):
            for x in range(w):
                v = heat[c, y, x]
                if not v >= thresholds[c]:
                    continue
                peak = True
                for yy in range(max(y - 1, 0), min(y + 2, h)):
                    for xx in range(max(x - 1, 0), min(x + 2, w)):
                        peak &= not heat[c, yy, xx] > v
                if peak:
                    found[0, n], found[1, n], found[2, n] = c, y, x
                    n += 1
    return found[0, :n].copy(), found[1, :n].copy(), found[2, :n].copy()


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
    from the fit. The peaks tried per type are the ``MAX_PEAKS_PER_TYPE`` nearest the regressed
    corner's direction from the centre (within ``NESTED_SECTOR_TAN``).

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
    z = np.asarray(z, np.complex128)
    kind, val = np.asarray(kind, np.int64), np.asarray(val, np.float64)
    found = []
    for c, v in zip(np.asarray(centres, float), np.asarray(vectors, float), strict=True):
        corners, scores = _nested(c, v, z, kind, val, max_residual)
        found.append(list(zip(corners, scores, strict=True)))
    return found


@njit(cache=True, error_model="numpy")
def _nested(
    centre: np.ndarray,
    vectors: np.ndarray,
    z: np.ndarray,
    kind: np.ndarray,
    val: np.ndarray,
    max_residual: float,
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`nested_gates` of one centre (2,) and its vectors (4, 2): (G, 4, 2) corners and
    (G, 4) scores."""
    c0 = centre[0] + 1j * centre[1]
    tmpl = vectors[:, 0] + 1j * vectors[:, 1]
    side = mean_side(vectors)
    # per corner type, the peaks near its direction, nearest the direction first
    pts = np.full((4, MAX_PEAKS_PER_TYPE + 1), np.nan + 0j)  # column 0: "no peak"
    vals = np.zeros((4, MAX_PEAKS_PER_TYPE + 1))
    counts = np.zeros(4, np.int64)
    tan = np.empty(len(z))
    for t in range(4):
        idx = np.empty(len(z), np.int64)
        m = 0
        for n in range(len(z)):
            if kind[n] != t or tmpl[t] == 0:  # (numba raises on a complex division by 0)
                continue
            w = (z[n] - c0) / tmpl[t]  # real: the scale along the corner's direction
            tan_n = abs(w.imag) / w.real
            if w.real > NESTED_SCALE[0] and w.real < NESTED_SCALE[1] and tan_n < NESTED_SECTOR_TAN:
                idx[m], tan[m] = n, tan_n
                m += 1
        order = np.argsort(tan[:m], kind="mergesort")[:MAX_PEAKS_PER_TYPE]
        counts[t] = len(order)
        for r in range(len(order)):
            pts[t, r + 1], vals[t, r + 1] = z[idx[order[r]]], val[idx[order[r]]]
    corners = np.empty((MAX_CHOICES, 4, 2))
    scores = np.zeros((MAX_CHOICES, 4))
    g = 0
    if not side >= 1e-3 or np.count_nonzero(counts) < NESTED_MIN_CORNERS:
        return corners[:0], scores[:0]
    choice = np.zeros(4, np.int64)
    q = np.empty(4, np.complex128)
    fit = np.empty(4, np.complex128)
    for number in range(np.prod(counts + 1)):
        rest = number  # the choice in C order: the first type's peak varies slowest
        for t in range(3, -1, -1):
            choice[t] = rest % (counts[t] + 1)
            rest //= counts[t] + 1
        have = choice > 0
        n = np.count_nonzero(have)
        if n < NESTED_MIN_CORNERS:
            continue
        p_mean, q_mean = 0j, 0j
        for t in range(4):
            q[t] = pts[t, choice[t]]
            if have[t]:
                p_mean += tmpl[t]
                q_mean += q[t]
        p_mean, q_mean = p_mean / n, q_mean / n
        num, den = 0j, 0.0
        for t in range(4):
            if have[t]:
                num += np.conj(tmpl[t] - p_mean) * (q[t] - q_mean)
                den += abs(tmpl[t] - p_mean) ** 2
        if not den > 0.0:  # the regressed corners chosen coincide: no shape to fit
            continue
        a = num / den  # scale * e^(i turn)
        misfit, centre_fit = 0.0, 0j
        for t in range(4):
            fit[t] = a * (tmpl[t] - p_mean) + q_mean
            centre_fit += fit[t] / 4
            if have[t]:
                misfit += abs(fit[t] - q[t]) ** 2
        scale = max(abs(a), 1e-9)
        resid = np.sqrt(misfit / n) / (scale * side)
        offset = abs(centre_fit - c0) / (scale * side)
        if (resid < max_residual and abs(np.arctan2(a.imag, a.real)) < NESTED_MAX_TURN
                and NESTED_SCALE[0] < scale < NESTED_SCALE[1] and offset < NESTED_MAX_OFFSET):  # fmt: skip
            for t in range(4):
                corner = q[t] if have[t] else fit[t]
                corners[g, t, 0], corners[g, t, 1] = corner.real, corner.imag
                scores[g, t] = vals[t, choice[t]]
            g += 1
    return corners[:g].copy(), scores[:g].copy()


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
    return _snap(
        np.ascontiguousarray(regressed, np.float64).reshape(-1, 4, 2),
        np.ascontiguousarray(pos, np.float64).reshape(-1, 2),
        np.asarray(kind, np.int64),
        np.asarray(val, np.float64),
        snap_radius,
    )


@njit(cache=True)
def _snap(
    regressed: np.ndarray, pos: np.ndarray, kind: np.ndarray, val: np.ndarray, snap_radius: float
) -> tuple[np.ndarray, np.ndarray]:
    corners = regressed.copy()
    scores = np.zeros(regressed.shape[:2])
    for i in range(len(regressed)):
        radius = max(1.5, snap_radius * mean_side(regressed[i]))
        for c in range(4):
            best, j = np.inf, -1
            for m in range(len(pos)):
                if kind[m] == c:
                    d = np.sqrt((pos[m, 0] - regressed[i, c, 0]) ** 2
                                + (pos[m, 1] - regressed[i, c, 1]) ** 2)  # fmt: skip
                    if d < best:
                        best, j = d, m
            if j >= 0 and best <= radius:
                corners[i, c] = pos[j]
                scores[i, c] = val[j]
    return corners, scores


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
    probs = np.array([cfg.centre_threshold] + [cfg.corner_threshold] * 4)
    with np.errstate(divide="ignore"):  # the heatmaps' thresholds as logits (0, 1: -inf, inf)
        thresholds = (np.log(probs) - np.log1p(-probs)).astype(np.float32)
    corners, corner_scores, scores, pos, kind, val = _decode(
        maps, thresholds, int(cfg.max_gates), float(cfg.snap_radius), bool(cfg.nested),
        float(cfg.nested_residual), float(cfg.nms_iou), int(cfg.min_snapped),
        float(cfg.sure_centre), float(scale[0]), float(scale[1]),
    )  # fmt: skip
    gates = list(zip(corners, corner_scores, scores.tolist(), strict=True))
    if not with_peaks:
        size = (scale[0] * out.shape[-1], scale[1] * out.shape[-2])
        return in_frame(gates, size, cfg.max_outside_px)
    ends = np.searchsorted(kind, np.arange(5)).tolist()
    return gates, [(pos[a:b] * np.asarray(scale) - 0.5, val[a:b])
                   for a, b in itertools.pairwise(ends)]  # fmt: skip


@njit(cache=True, error_model="numpy")
def _decode(maps, thresholds, max_gates, snap_radius, nested, nested_residual, nms_iou,
            min_snapped, sure_centre, sx, sy):  # fmt: skip
    """:func:`decode` on the network's (15, H, W) output, its heatmaps' peaks found on the
    logits (at or above (5,) logit ``thresholds``; the sigmoid, monotonic, is taken only at the
    peaks): the gates' corners (G, 4, 2) pixels, corner scores (G, 4) and scores (G,), and
    every corner peak's position (M, 2) cells, type (M,) and score (M,), by type.

    Each centre peak's regressed gate, corners snapped, is a hypothesis; unless a better one
    overlaps it (the same gate), so are the gates nested in or around it. The hypotheses, best
    first, are then reported unless unconfirmed by their corners (``min_snapped``, ``sure_centre``)
    or overlapping a better reported one."""
    ks, ys, xs = _peaks(maps[:5], thresholds)
    reg = maps[5:]
    n_centres = np.searchsorted(ks, 1)
    centre_scores = np.empty(n_centres)
    for i in range(n_centres):
        centre_scores[i] = _sigmoid(maps[0, ys[i], xs[i]])
    order = np.argsort(-centre_scores, kind="mergesort")[:max_gates]
    p = len(order)
    centres, vectors = np.empty((p, 2)), np.empty((p, 4, 2))
    for i in range(p):
        y, x = ys[order[i]], xs[order[i]]
        centres[i, 0], centres[i, 1] = x, y
        for c in range(4):
            for d in range(2):
                vectors[i, c, d] = np.float32(VECTOR_SCALE) * reg[2 + 2 * c + d, y, x]
    m = len(ks) - n_centres  # corner peaks, each at its regressed sub-cell position
    pos, kind, val = np.empty((m, 2)), ks[n_centres:] - 1, np.empty(m)
    for i in range(m):
        y, x = ys[n_centres + i], xs[n_centres + i]
        pos[i, 0], pos[i, 1] = x + reg[0, y, x], y + reg[1, y, x]
        val[i] = _sigmoid(maps[ks[n_centres + i], y, x])
    z = pos[:, 0] + 1j * pos[:, 1]
    regressed = vectors.copy()
    for i in range(p):
        regressed[i] += centres[i]
    snapped, snapped_scores = _snap(regressed, pos, kind, val, snap_radius)
    # hypotheses: corners (cells), corner scores, score
    cap = p * (1 + MAX_CHOICES) if nested else p
    hyp, hyp_corner_scores, hyp_scores = np.empty((cap, 4, 2)), np.empty((cap, 4)), np.empty(cap)
    n = 0
    primary = np.zeros(p, np.bool_)
    for i in range(p):
        hyp[n], hyp_corner_scores[n] = snapped[i], snapped_scores[i]
        hyp_scores[n] = centre_scores[order[i]]
        n += 1
        # a weaker peak of a gate already searched around is not searched again
        primary[i] = not _overlaps(snapped[i], snapped, primary[:i], nms_iou)
        if primary[i] and nested:
            corners, scores = _nested(centres[i], vectors[i], z, kind, val, nested_residual)
            for g in range(len(corners)):
                hyp[n], hyp_corner_scores[n] = corners[g], scores[g]
                hyp_scores[n] = centre_scores[order[i]] * scores[g].mean()
                n += 1
    # the best hypotheses, in pixels, none overlapping a better one
    pixels = np.empty((n, 4, 2))
    for i in range(n):
        pixels[i, :, 0], pixels[i, :, 1] = hyp[i, :, 0] * sx - 0.5, hyp[i, :, 1] * sy - 0.5
    kept = np.zeros(n, np.bool_)
    chosen = np.empty(min(n, max_gates), np.int64)
    count = 0
    for i in np.argsort(-hyp_scores[:n], kind="mergesort"):
        if count == max_gates:
            break
        if np.count_nonzero(hyp_corner_scores[i]) < min_snapped and hyp_scores[i] < sure_centre:
            continue
        if not _overlaps(pixels[i], pixels, kept, nms_iou):
            kept[i] = True
            chosen[count] = i
            count += 1
    chosen = chosen[:count]
    return pixels[chosen], hyp_corner_scores[chosen], hyp_scores[chosen], pos, kind, val


@njit(cache=True)
def _sigmoid(x: np.float32) -> np.float32:
    """The logistic function in float32 (as numpy computes it on a float32 map)."""
    return np.float32(1.0) / (np.float32(1.0) + np.exp(-x))


@njit(cache=True)
def _overlaps(quad: np.ndarray, others: np.ndarray, among: np.ndarray, nms_iou: float) -> bool:
    """Whether a (4, 2) quadrilateral overlaps any of ``others[among]`` by more than ``nms_iou``
    (intersection over union; bounding boxes first, which rules out most)."""
    x0, y0 = quad[:, 0].min(), quad[:, 1].min()
    x1, y1 = quad[:, 0].max(), quad[:, 1].max()
    for j in range(len(among)):
        if not among[j]:
            continue
        o = others[j]
        if x1 < o[:, 0].min() or o[:, 0].max() < x0 or y1 < o[:, 1].min() or o[:, 1].max() < y0:
            continue
        if quad_iou_kernel(quad, o) > nms_iou:
            return True
    return False


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
