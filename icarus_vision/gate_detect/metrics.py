"""Detection metrics: gate matching, precision/recall, corner error and PCK, binned breakdowns.

Matching rule: detections are taken in decreasing score; each is matched to the unmatched
ground-truth gate with the smallest mean distance between corresponding corners (TL-TL, TR-TR, ...),
if that distance is at most ``max(4 px, 0.25 x the ground truth's mean side)``. One-to-one.

Which gates count: gates seen from behind are labelled like any other (the frame looks the same from
both sides; their corners are named as seen), and a ground-truth gate counts in the figures when all four corners lie in the image,
at least three are visible (not occluded), and its opening's mean side is at least ``min_gate_px``.
Other labelled gates are *ignored*: missing them is no error, and a detection matched to one is
neither a true nor a false positive; an unmatched detection smaller than ``min_gate_px`` is ignored
too. Precision = TP / (TP + FP), recall = matched counted gates / counted gates. Corner errors
are over the four corners of the matched counted gates; PCK@r is the fraction of the counted gates'
corners detected within r pixels (corners of missed gates count as failures).
"""

from __future__ import annotations

import numpy as np

DISTANCE_BINS_M = (0.0, 2.0, 4.0, 8.0, 12.0, 16.0, np.inf)
"""Edges of the distance breakdown, m."""
SIZE_BINS_PX = (0.0, 20.0, 40.0, 80.0, 160.0, np.inf)
"""Edges of the apparent-size breakdown (mean side of the opening), pixels."""


NEXT_CORNER = [1, 2, 3, 0]
"""Index of each corner's successor around a quadrilateral (``q[..., NEXT_CORNER, :]`` is
``np.roll(q, -1, axis=-2)``, several times faster on the few quadrilaterals of a frame)."""


def mean_sides(quads: np.ndarray) -> np.ndarray:
    """Mean side lengths of (..., 4, 2) quadrilaterals -> (...), pixels (NaN where a corner is)."""
    q = np.asarray(quads, float)
    d = q - q[..., NEXT_CORNER, :]
    return np.sqrt((d * d).sum(axis=-1)).mean(axis=-1)


def mean_side(corners: np.ndarray) -> float:
    """Mean side length of a (4, 2) quadrilateral, pixels (NaN if a corner is NaN)."""
    return float(mean_sides(corners))


def match_tolerance(side: float) -> float:
    """Largest mean corner distance at which a detection matches a gate of mean side ``side``
    px (the module docstring's rule)."""
    return max(4.0, 0.25 * side)


def match(
    pred: list[np.ndarray], scores: list[float], truth: list[np.ndarray]
) -> dict[int, tuple[int, float]]:
    """Greedy one-to-one matching (see the module docstring).

    Args:
        pred: detected corners, (4, 2) pixels each.
        scores: their gate scores.
        truth: true corners, (4, 2) pixels each (NaN corners never match).

    Returns:
        {detection index: (truth index, mean corner distance px)}.
    """
    out: dict[int, tuple[int, float]] = {}
    taken: set[int] = set()
    tol = [match_tolerance(mean_side(t)) for t in truth]
    for i in np.argsort(-np.asarray(scores, float), kind="stable"):
        best, best_d = -1, np.inf
        for j, t in enumerate(truth):
            if j in taken:
                continue
            d = float(np.linalg.norm(pred[i] - t, axis=1).mean())
            if d <= tol[j] and d < best_d:
                best, best_d = j, d
        if best >= 0:
            out[int(i)] = (best, best_d)
            taken.add(best)
    return out


def evaluable(corners: np.ndarray, visibility: np.ndarray) -> bool:
    """All four corners in the image and at least three visible (before the size cut)."""
    return bool(
        np.isfinite(corners).all() and (visibility > 0).all() and (visibility == 2).sum() >= 3
    )


def summarize(gts: list[dict], preds: list[dict], min_gate_px: float) -> dict:
    """Headline figures of one set of gates.

    Args:
        gts: per ground-truth gate: ``evaluable`` bool, ``side`` px, ``matched`` bool and
            ``errors`` (4,) px corner errors (when matched).
        preds: per detection: ``status`` "tp", "fp" or "ignored", and ``side`` px.
        min_gate_px: smallest counted gate side.

    Returns:
        gates, precision, recall, false_positives (count), corner_error_px {mean, median},
        corner_error_side {median} (corner errors as fractions of their gate's mean side),
        pck {2px, 5px}.
    """
    counted = [g for g in gts if g["evaluable"] and g["side"] >= min_gate_px]
    tp = sum(p["status"] == "tp" for p in preds)
    fp = sum(p["status"] == "fp" for p in preds)
    errs = np.concatenate([g["errors"] for g in counted if g["matched"]] or [np.zeros(0)])
    rel = np.concatenate(
        [g["errors"] / g["side"] for g in counted if g["matched"]] or [np.zeros(0)]
    )
    n_corners = 4 * len(counted)

    def r(x: float) -> float | None:
        return None if x is None or not np.isfinite(x) else round(float(x), 4)

    return {
        "gates": len(counted),
        "precision": r(tp / (tp + fp)) if tp + fp else None,
        "recall": r(sum(g["matched"] for g in counted) / len(counted)) if counted else None,
        "false_positives": fp,
        "corner_error_px": {
            "mean": r(errs.mean()) if len(errs) else None,
            "median": r(np.median(errs)) if len(errs) else None,
        },
        "corner_error_side": {"median": r(np.median(rel)) if len(rel) else None},
        "pck": {
            "2px": r((errs <= 2.0).sum() / n_corners) if n_corners else None,
            "5px": r((errs <= 5.0).sum() / n_corners) if n_corners else None,
        },
    }


def evaluate_image(
    pred: list[tuple[np.ndarray, float]],
    truth: list[tuple[np.ndarray, np.ndarray, float]],
    min_gate_px: float,
) -> tuple[list[dict], list[dict]]:
    """Records of one image for :func:`summarize`.

    Args:
        pred: (corners (4, 2), score) per detection.
        truth: (corners (4, 2), visibility (4,), distance m) per labelled gate.
        min_gate_px: smallest counted gate side.

    Returns:
        (gt records, detection records); gt records also carry ``distance``, ``corners``,
        ``pred_corners`` (matched) ; detection records carry ``side`` and ``distance`` (of the
        matched gate, else None).
    """
    m = match([p[0] for p in pred], [p[1] for p in pred], [t[0] for t in truth])
    by_gt = {j: (i, d) for i, (j, d) in m.items()}
    gts = []
    for j, (corners, vis, dist) in enumerate(truth):
        i = by_gt.get(j, (None,))[0]
        errors = None if i is None else np.linalg.norm(pred[i][0] - corners, axis=1)
        gts.append({
            "evaluable": evaluable(corners, vis), "side": mean_side(corners), "distance": dist,
            "matched": i is not None, "errors": errors, "corners": corners,
            "pred_corners": None if i is None else pred[i][0],
        })  # fmt: skip
    preds = []
    for i, (corners, _) in enumerate(pred):
        side = mean_side(corners)
        if i in m:
            g = gts[m[i][0]]
            counted = g["evaluable"] and g["side"] >= min_gate_px
            status, dist = ("tp" if counted else "ignored"), g["distance"]
        else:
            status, dist = ("fp" if side >= min_gate_px else "ignored"), None
        preds.append({"status": status, "side": side, "distance": dist})
    return gts, preds


def binned(
    gts: list[dict], preds: list[dict], key: str, edges: tuple[float, ...], min_gate_px: float
) -> list[dict]:
    """:func:`summarize` per bin of ``key`` (``distance`` m or ``side`` px); a false positive
    is put in the bin of its own ``key`` (its side, or for distance the estimate in ``distance``)."""
    out = []
    for lo, hi in zip(edges[:-1], edges[1:], strict=True):
        s = summarize(
            [g for g in gts if _inside(g[key], lo, hi)],
            [p for p in preds if _inside(p[key], lo, hi)],
            min_gate_px,
        )
        out.append({"min": lo, "max": None if not np.isfinite(hi) else hi, **s})
    return out


def _inside(x: float | None, lo: float, hi: float) -> bool:
    return x is not None and bool(np.isfinite(x)) and lo <= x < hi


CI_FIGURES = ("precision", "recall", "corner_error_median_px", "pck_2px", "pck_5px")
"""The headline figures :func:`confidence` gives intervals for."""


def confidence(
    images: list[tuple[list[dict], list[dict]]],
    min_gate_px: float,
    resamples: int = 1000,
    level: float = 0.95,
    seed: int = 0,
) -> dict:
    """Percentile-bootstrap confidence intervals of the headline figures (:data:`CI_FIGURES`).

    Whole images are resampled with replacement, ``resamples`` times: the gates of one frame
    share its light, background and camera motion, so they are not independent draws.

    Args:
        images: per image, its :func:`evaluate_image` records ``(gts, preds)``.
        min_gate_px: smallest counted gate side.
        resamples: bootstrap resamples.
        level: coverage of each interval.
        seed: seed of the resampling (same seed, same intervals).

    Returns:
        {figure: [low, high]} (None where a figure is undefined in some resample), plus
        ``resamples`` and ``level``.
    """
    if not 0.0 < level < 1.0:
        raise ValueError(f"level must be in (0, 1), got {level}")
    if resamples < 1:
        raise ValueError(f"resamples must be >= 1, got {resamples}")
    n = len(images)
    counts = np.zeros((n, 6))  # tp, fp, counted gates, matched counted, corners <= 2 px, <= 5 px
    errors, owner = [], []
    for i, (gts, preds) in enumerate(images):
        counted = [g for g in gts if g["evaluable"] and g["side"] >= min_gate_px]
        e = np.concatenate([g["errors"] for g in counted if g["matched"]] or [np.zeros(0)])
        counts[i] = (sum(p["status"] == "tp" for p in preds),
                     sum(p["status"] == "fp" for p in preds), len(counted),
                     sum(g["matched"] for g in counted), (e <= 2.0).sum(), (e <= 5.0).sum())  # fmt: skip
        errors.append(e)
        owner.append(np.full(len(e), i))
    rng = np.random.default_rng(seed)
    weights = rng.multinomial(n, np.full(n, 1.0 / max(n, 1)), size=resamples).astype(float)
    tp, fp, gates, matched, within2, within5 = (weights @ counts).T
    e = np.concatenate(errors or [np.zeros(0)])
    order = np.argsort(e, kind="stable")
    e, owner_sorted = e[order], np.concatenate(owner or [np.zeros(0, int)])[order]
    with np.errstate(invalid="ignore", divide="ignore"):
        figures = {
            "precision": tp / (tp + fp),
            "recall": matched / gates,
            "corner_error_median_px": _weighted_medians(e, weights[:, owner_sorted]),
            "pck_2px": within2 / (4.0 * gates),
            "pck_5px": within5 / (4.0 * gates),
        }
    q = [100.0 * (1.0 - level) / 2.0, 100.0 * (1.0 + level) / 2.0]
    out: dict = {}
    for k, v in figures.items():
        ok = np.isfinite(v).all() and len(v)
        out[k] = [round(float(x), 4) for x in np.percentile(v, q)] if ok else None
    return out | {"resamples": resamples, "level": level}


def _weighted_medians(values: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """(R,) lower medians of sorted ``values`` (M,) under each row of (R, M) ``weights`` (NaN
    where a row's weights are all 0)."""
    if not values.size:
        return np.full(len(weights), np.nan)
    cum = np.cumsum(weights, axis=1)
    total = cum[:, -1:]
    k = np.minimum((cum < 0.5 * total).sum(axis=1), values.size - 1)
    return np.where(total[:, 0] > 0, values[k], np.nan)
