"""Second stage of the CNN detector: verify each candidate gate and correct its corners.

The corner network (first stage) proposes gates; most of its remaining errors are gate-like things
that perspective makes look square, and gates whose corners snapped to the wrong peak (often the
same corner of a gate seen through this one, or a hidden corner). Each candidate's neighbourhood is
rectified by the homography that maps its four corners to a fixed square in a small patch
(``RefineConfig.patch`` pixels, the opening ``patch - 2 * margin`` wide): a true gate then always
looks like a square frame in the middle, at one scale, whatever its distance and viewing angle.
A tiny network (:class:`RefineNet`) reads the patch and returns

* a logit: is this a gate whose opening lies about where the candidate says (the reported score
  is its probability times the first stage's score),
* per corner, the true corner's offset from where the candidate put it, in the patch, in units of
  the opening's side.

The geometry of rectification lives in ``rectify.py``. The corrected corners go back to the
camera image through the inverse homography; optionally each is then snapped to the first stage's
nearest peak of its corner type within ``snap`` of the gate's side (on val, the refiner's own
corners were the better ones, so the shipped detector does not).

Optionally (``RefineConfig.mirror``) each candidate is read a second time mirrored, and the two
readings are averaged; and (``RefineConfig.passes``) read again where the last reading put its
corners, unless that reading barely moved them (``RefineConfig.reread_min_px``).

Shapes: patches (B, 3, P, P) float in [0, 1]; network output (B, 9).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
import torch
from torch import nn

from icarus_vision.gate_detect.cnn.model import conv_bn_relu
from icarus_vision.gate_detect.cnn.polygon import quad_iou
from icarus_vision.gate_detect.cnn.rectify import (
    extract,
    homographies,
    mirrored,
    network_patches,
    offsets_to_corners,
    patch_to_image,
    settle,
    squareness,
    usable,
)
from icarus_vision.gate_detect.cnn.runtime import run_network
from icarus_vision.gate_detect.metrics import mean_sides


@dataclass(frozen=True)
class RefineConfig:
    """Architecture of the refiner and how its output is used (stored in ``detector.json``)."""

    patch: int = 48
    """Side of the rectified patch, pixels (a multiple of 8)."""
    margin: int = 8
    """Patch pixels between the candidate's opening and the patch border on each side."""
    widths: tuple[int, int, int] = (16, 32, 64)
    """Channels of the three stride-2 stages."""
    hidden: int = 64
    """Units of the fully connected layer."""
    threshold: float = 0.25
    """Smallest score of a reported gate: the refiner's gate probability times the first stage's
    score."""
    snap: float = 0.0
    """A corrected corner moves to the first stage's nearest peak of its type within this
    fraction of the gate's mean side (at least ``snap_min_px``); 0: no snapping."""
    snap_min_px: float = 1.5
    """Smallest snap radius, camera pixels."""
    mirror: bool = False
    """Also read each candidate mirrored and average the two readings (test-time augmentation:
    twice the refiner's work)."""
    passes: int = 1
    """Readings of each candidate: each after the first reads the patch again where the last one
    put the corners, and its gate probability and corners replace the last one's (the patch is
    then better centred; on val, a second pass raised PCK@5px: README)."""
    reread_min_px: float = 0.0
    """A candidate is read again in the next pass only if the last reading moved one of its
    corners by at least this many patch pixels along x or y (camera pixels times ``side`` over
    the candidate's mean side): a patch barely moved reads nearly the same. 0: always."""
    candidate_iou: float = 0.85
    """First-stage candidates overlapping a better-scored one by more than this (intersection
    over union) are dropped before the refiner reads them (the refiner's own output is
    de-duplicated at the decoding's ``nms_iou``). Looser than that, gates seen through a gate of
    nearly the same apparent size each keep their candidate. (Training reads the candidates of
    ``refine_train.CANDIDATES``, de-duplicated at ``RefineTrainConfig.candidate_iou``, 0.5 by
    default; tuning and the detector, these.)"""
    max_skew: float = 0.0
    """A gate whose opening's mean side is at least ``skew_min_px`` is reported only if, seen
    by a nominal camera (:data:`NOMINAL_HFOV_DEG`), its opening is square in 3-D within a ratio
    of sides of e^``max_skew`` (:func:`squareness`): gates are square, and most gate-like
    distractors are not, though the patch, rectified to a square, hides it. 0: no check."""
    skew_min_px: float = 30.0
    """Smallest mean side of a gate whose squareness is checked, pixels (the 3-D aspect of a
    smaller one is too uncertain to drop it for that alone)."""
    small_skew_score: float = 0.0
    """A gate of ``small_skew_min_px`` up to ``skew_min_px`` that fails ``max_skew`` is reported
    only if it scores at least this: its aspect is uncertain, so it only drops a weak candidate
    (on val most such candidates scoring under 0.5 were distractors, most over it gates).
    0: gates under ``skew_min_px`` are never checked."""
    small_skew_min_px: float = 20.0
    """Smallest mean side of a gate ``small_skew_score`` applies to, pixels."""
    square_hfov_deg: float = 0.0
    """Horizontal field of view of the nominal camera under which the refiner is also told how
    square each candidate is in 3-D (:func:`squareness`), degrees; 0: not told. (Measured on
    val, a refiner told so, under 95 degrees, did no better: README.)"""

    @property
    def side(self) -> int:
        """Side of the opening in the patch, pixels."""
        return self.patch - 2 * self.margin

    def to_dict(self) -> dict:
        return {k: list(v) if isinstance(v, tuple) else v for k, v in asdict(self).items()}

    @property
    def num_geom(self) -> int:
        """Inputs besides the patch (:func:`geometry`)."""
        return 13 if self.square_hfov_deg else 11

    @classmethod
    def from_dict(cls, d: dict) -> RefineConfig:
        d = {"candidate_iou": 0.5, **d}  # files written before it existed decoded at 0.5
        return cls(**{k: tuple(v) if isinstance(v, list) else v for k, v in d.items()})


NOMINAL_HFOV_DEG = 95.0
"""Field of view of the camera under which ``RefineConfig.max_skew`` is checked, degrees (the
middle of the dataset recipe's 80-110 degrees; another field of view shifts the aspect a
little)."""


def geometry(
    quads: np.ndarray, scores: np.ndarray, image_size: tuple[int, int], cfg: RefineConfig
) -> np.ndarray:
    """(N, ``cfg.num_geom``) float32 inputs of the refiner besides the patch: where the
    candidate is in the image (rectifying hides its shape: any quadrilateral maps to the square),
    the first stage's scores and, with ``cfg.square_hfov_deg``, its :func:`squareness`.

    Args:
        quads: (N, 4, 2) candidate corners, camera pixels.
        scores: (N, 3) first-stage centre score, mean corner score, fraction of snapped corners.
        image_size: (W, H) of the camera frame.
        cfg: the refiner's configuration.
    """
    w, h = image_size
    q = (quads - (w / 2.0, h / 2.0)) / w
    parts = [q.reshape(-1, 8), scores]
    if cfg.square_hfov_deg:
        parts.append(squareness(quads, image_size, cfg.square_hfov_deg))
    return np.concatenate(parts, axis=1).astype(np.float32)


def stage_scores(gates: list[tuple[np.ndarray, np.ndarray, float]]) -> np.ndarray:
    """(N, 3) :func:`geometry` scores of first-stage candidates."""
    return np.array(
        [[s, cs.mean(), np.count_nonzero(cs) / 4.0] for _, cs, s in gates], np.float32
    ).reshape(-1, 3)


class RefineNet(nn.Module):
    """Three stride-2 stages and a fully connected head: (B, 3, P, P), (B, G) -> (B, 9), G =
    :attr:`RefineConfig.num_geom`.

    Output: column 0 the gate logit; columns 1-8 (dx, dy) per corner TL, TR, BR, BL, patch
    pixels divided by :attr:`RefineConfig.side`.
    """

    def __init__(self, cfg: RefineConfig = RefineConfig()) -> None:
        super().__init__()
        if cfg.patch % 8 or not 0 < cfg.margin < cfg.patch // 2:
            raise ValueError(f"patch must be a multiple of 8 with 0 < margin < patch/2: {cfg}")
        if cfg.passes < 1 or not 0.0 < cfg.candidate_iou <= 1.0 or cfg.reread_min_px < 0:
            raise ValueError(
                f"passes must be >= 1, candidate_iou in (0, 1] and reread_min_px >= 0: {cfg}"
            )
        c1, c2, c3 = cfg.widths
        self.cfg = cfg
        self.features = nn.Sequential(
            conv_bn_relu(3, c1, 2),
            conv_bn_relu(c1, c2, 2),
            conv_bn_relu(c2, c2),
            conv_bn_relu(c2, c3, 2),
            conv_bn_relu(c3, c3),
        )
        cells = (cfg.patch // 8) ** 2
        self.hidden = nn.Sequential(nn.Linear(c3 * cells + cfg.num_geom, cfg.hidden), nn.ReLU())
        self.out = nn.Linear(cfg.hidden, 9)

    def forward(self, x: torch.Tensor, geom: torch.Tensor) -> torch.Tensor:
        f = torch.cat([self.features(x).flatten(1), geom.to(x.dtype)], dim=1)
        return self.out(self.hidden(f))


def snap_to_peaks(
    corners: np.ndarray, peaks: list[tuple[np.ndarray, np.ndarray]], cfg: RefineConfig
) -> tuple[np.ndarray, np.ndarray]:
    """Move each corrected corner to the nearest first-stage peak of its type within the radius.

    Args:
        corners: (N, 4, 2) camera pixels.
        peaks: per corner type, (positions (M, 2) camera pixels, scores (M,)).

    Returns:
        (corners (N, 4, 2), snapped peak scores (N, 4), 0 where none was near).
    """
    out = corners.copy()
    scores = np.zeros(corners.shape[:2])
    if cfg.snap <= 0 or not len(corners):
        return out, scores
    radius = np.maximum(cfg.snap * mean_sides(corners), cfg.snap_min_px)
    for k, (pos, val) in enumerate(peaks):
        if not len(pos):
            continue
        d = np.linalg.norm(corners[:, k, None, :] - pos[None], axis=-1)  # (N, M)
        j = d.argmin(axis=1)
        near = d[np.arange(len(d)), j] <= radius
        out[near, k] = pos[j[near]]
        scores[near, k] = val[j[near]]
    return out, scores


@dataclass
class Verdicts:
    """The refiner's output for one image's candidates (what :func:`select` chooses from).

    Attributes:
        prob: (N,) gate probability of each candidate it looked at.
        stage: (N,) the first stage's score of each.
        corners: (N, 4, 2) corrected corners, camera pixels.
        skew: (N,) |log of the ratio of the opening's sides| in 3-D under the nominal camera
            (:func:`squareness`); None: not known (never fails ``RefineConfig.max_skew``).
    """

    prob: np.ndarray
    stage: np.ndarray
    corners: np.ndarray
    skew: np.ndarray | None = None

    @classmethod
    def empty(cls) -> Verdicts:
        return cls(np.zeros(0), np.zeros(0), np.zeros((0, 4, 2)), np.zeros(0))


def verdicts(
    net: nn.Module,
    image: np.ndarray,
    gates: list[tuple[np.ndarray, np.ndarray, float]],
    cfg: RefineConfig,
    floor: float | None = None,
    dtype: torch.dtype = torch.float32,
    skew: bool = True,
) -> Verdicts:
    """Run the refiner on one image's candidates.

    Args:
        net: a trained :class:`RefineNet` (or its traced form), eval mode.
        image: (H, W, 3) uint8 RGB camera frame.
        gates: first-stage candidates ``(corners (4, 2) px, corner_scores (4,), score)``.
        cfg: patch geometry; with ``cfg.mirror``, each candidate is also read mirrored and the
            two readings are averaged (logits, and corners in the image); ``cfg.passes``
            readings, each where the last one put the corners.
        floor: candidates the first stage scored under this are not looked at (default
            ``cfg.threshold``: the refiner's probability is at most 1, so they cannot pass).
        dtype: the network's input dtype.
        skew: measure each candidate's :func:`skews` (else ``Verdicts.skew`` is None).
    """
    floor = cfg.threshold if floor is None else floor
    gates = [g for g in gates if g[2] >= floor]
    if not gates:
        return Verdicts.empty()
    quads = np.array([g[0] for g in gates], np.float64)
    ok = usable(quads)
    if not ok.any():
        return Verdicts.empty()
    quads, scores = quads[ok], stage_scores(gates)[ok]
    logit = np.zeros(len(quads))
    todo = np.arange(len(quads))  # the candidates read in this pass
    for _ in range(cfg.passes):
        logit[todo], corners = read(net, image, quads[todo], scores[todo], cfg, dtype)
        quads[todo], shift = settle(quads[todo], corners, cfg.side)
        todo = todo[shift >= cfg.reread_min_px]
        if not len(todo):
            break
    stage = np.array([g[2] for g in gates])[ok]
    measured = skews(quads, image.shape[1::-1]) if skew else None
    return Verdicts(1.0 / (1.0 + np.exp(-logit)), stage, quads, measured)


def skews(quads: np.ndarray, image_size: tuple[int, int]) -> np.ndarray:
    """(N,) |log of the ratio of the sides| in 3-D of (N, 4, 2) openings in a (W, H) frame,
    under the nominal camera (:func:`squareness`, :data:`NOMINAL_HFOV_DEG`)."""
    return np.abs(squareness(quads, image_size, NOMINAL_HFOV_DEG)[:, 0])


def square_enough(
    skew: np.ndarray | None, corners: np.ndarray, score: np.ndarray, cfg: RefineConfig
) -> np.ndarray:
    """(N,) whether each of (N, 4, 2) openings with (N,) scores passes ``cfg.max_skew`` given
    its :func:`skews` (None: not known, passes): square enough, smaller than
    ``cfg.skew_min_px`` (and, from ``cfg.small_skew_min_px``, scoring at least
    ``cfg.small_skew_score``), or no check."""
    if cfg.max_skew <= 0 or skew is None:
        return np.ones(len(corners), bool)
    side = mean_sides(corners)
    weak = (side >= cfg.small_skew_min_px) & (score < cfg.small_skew_score)
    return (skew <= cfg.max_skew) | ((side < cfg.skew_min_px) & ~weak)


def keep_square(
    found: list[tuple[np.ndarray, np.ndarray, float]],
    image_size: tuple[int, int],
    cfg: RefineConfig,
) -> list[tuple[np.ndarray, np.ndarray, float]]:
    """The gates of ``found`` (``(corners (4, 2), corner_scores, score)`` in a (W, H) frame)
    that pass ``cfg.max_skew`` (:func:`square_enough`) on their corners as they are: the
    detector checks the zoom stage's corners so."""
    if cfg.max_skew <= 0 or not found:
        return found
    q = np.stack([c for c, _, _ in found])
    ok = square_enough(skews(q, image_size), q, np.array([s for _, _, s in found]), cfg)
    return [f for f, keep in zip(found, ok, strict=True) if keep]


def read(
    net: nn.Module,
    image: np.ndarray,
    quads: np.ndarray,
    scores: np.ndarray,
    cfg: RefineConfig,
    dtype: torch.dtype = torch.float32,
) -> tuple[np.ndarray, np.ndarray]:
    """One reading of (N, 4, 2) usable candidates with (N, 3) first-stage scores: (N,) gate
    logits and (N, 4, 2) corrected corners, camera pixels (``cfg.mirror``: see :func:`verdicts`)."""
    n, size = len(quads), image.shape[1::-1]
    if cfg.mirror:
        where = mirrored(quads, size[0])[1]
        geom = geometry(np.concatenate([quads, where]), np.concatenate([scores, scores]), size, cfg)
    else:
        geom = geometry(quads, scores, size, cfg)
    h = homographies(quads, cfg)
    back = patch_to_image(quads, cfg)  # before the network, while this code is in the caches
    # The mirrored reading rectifies the candidate with its corner order swapped; as the square
    # is symmetric, that patch is this one mirrored (within one grey level of interpolation):
    # flipped here rather than warped again.
    out = run_network(net, network_patches(extract(image, h, cfg), cfg.mirror), geom, dtype=dtype)
    if not cfg.mirror:
        return out[:, 0], offsets_to_corners(h, out[:, 1:], cfg, back=back)
    corners = offsets_to_corners(h, out[:n, 1:], cfg, mirrored=out[n:, 1:], back=back)
    return 0.5 * (out[:n, 0] + out[n:, 0]), corners


def select(
    v: Verdicts,
    peaks: list[tuple[np.ndarray, np.ndarray]],
    cfg: RefineConfig,
    nms_iou: float = 0.5,
) -> list[tuple[np.ndarray, np.ndarray, float]]:
    """The gates among one image's :class:`Verdicts`: score at least ``cfg.threshold``, square
    enough (``cfg.max_skew``), corners (snapped when ``cfg.snap``) finite, not overlapping a
    better gate by more than ``nms_iou``.

    Returns:
        per gate ``(corners (4, 2) px, corner_scores (4,), score)``, best first.
    """
    score = v.prob * v.stage
    ok = (score >= cfg.threshold) & square_enough(v.skew, v.corners, score, cfg)
    keep = np.flatnonzero(ok)
    if not len(keep):
        return []
    keep = keep[np.argsort(-score[keep], kind="stable")]
    corners, snapped = snap_to_peaks(v.corners[keep], peaks, cfg)
    return [(corners[j], np.where(snapped[j] > 0, snapped[j], v.prob[keep[j]]), float(score[keep[j]]))
            for j in non_overlapping(corners, nms_iou)]  # fmt: skip


def non_overlapping(quads: np.ndarray, nms_iou: float) -> list[int]:
    """Indices of the (N, 4, 2) quadrilaterals, given best first, that are finite and overlap
    no earlier kept one by more than ``nms_iou`` (intersection over union): greedy NMS."""
    kept: list[int] = []
    for i, c in enumerate(quads):
        if np.isfinite(c).all() and all(quad_iou(c, quads[k]) <= nms_iou for k in kept):
            kept.append(i)
    return kept


def refine(
    net: nn.Module,
    image: np.ndarray,
    gates: list[tuple[np.ndarray, np.ndarray, float]],
    peaks: list[tuple[np.ndarray, np.ndarray]],
    cfg: RefineConfig,
    nms_iou: float = 0.5,
    dtype: torch.dtype = torch.float32,
) -> list[tuple[np.ndarray, np.ndarray, float]]:
    """Verify and correct one image's candidate gates (:func:`verdicts`, then :func:`select`).

    Args:
        net: a trained :class:`RefineNet` (or its traced form), eval mode.
        image: (H, W, 3) uint8 RGB camera frame.
        gates: first-stage candidates ``(corners (4, 2) px, corner_scores (4,), score)``.
        peaks: the first stage's corner peaks, per type ``(positions (M, 2) px, scores (M,))``.
        cfg: patch geometry and thresholds.
        nms_iou: a gate overlapping a more probable one by more than this is dropped.
        dtype: the network's input dtype.

    Returns:
        per gate ``(corners (4, 2) px, corner_scores (4,), score)``, best first. The score is the
        refiner's gate probability times the first stage's score: on the val split this product
        separated gates from the rest better than either alone (README).
    """
    v = verdicts(net, image, gates, cfg, dtype=dtype, skew=cfg.max_skew > 0)
    return select(v, peaks, cfg, nms_iou)
