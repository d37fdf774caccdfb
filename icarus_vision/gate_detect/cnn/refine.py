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

The corrected corners go back to the camera image through the inverse homography; optionally each
is then snapped to the first stage's nearest peak of its corner type within ``snap`` of the gate's
side (on val, the refiner's own corners were the better ones, so the shipped detector does not).

Shapes: patches (B, 3, P, P) float in [0, 1]; network output (B, 9).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import cv2
import numpy as np
import torch
from torch import nn

from icarus_vision.gate_detect.cnn.model import conv_bn_relu
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

    @property
    def side(self) -> int:
        """Side of the opening in the patch, pixels."""
        return self.patch - 2 * self.margin

    def to_dict(self) -> dict:
        return {k: list(v) if isinstance(v, tuple) else v for k, v in asdict(self).items()}

    @classmethod
    def from_dict(cls, d: dict) -> RefineConfig:
        return cls(**{k: tuple(v) if isinstance(v, list) else v for k, v in d.items()})


NUM_GEOM = 11
"""Inputs besides the patch (:func:`geometry`): where the candidate is in the image (rectifying
hides its shape: any quadrilateral maps to the square) and the first stage's scores."""


def geometry(quads: np.ndarray, scores: np.ndarray, image_size: tuple[int, int]) -> np.ndarray:
    """(N, 11) float32 inputs of the refiner besides the patch.

    Args:
        quads: (N, 4, 2) candidate corners, camera pixels.
        scores: (N, 3) first-stage centre score, mean corner score, fraction of snapped corners.
        image_size: (W, H) of the camera frame.
    """
    w, h = image_size
    q = (quads - (w / 2.0, h / 2.0)) / w
    return np.concatenate([q.reshape(-1, 8), scores], axis=1).astype(np.float32)


def stage_scores(gates: list[tuple[np.ndarray, np.ndarray, float]]) -> np.ndarray:
    """(N, 3) :func:`geometry` scores of first-stage candidates."""
    return np.array(
        [[s, cs.mean(), np.count_nonzero(cs) / 4.0] for _, cs, s in gates], np.float32
    ).reshape(-1, 3)


class RefineNet(nn.Module):
    """Three stride-2 stages and a fully connected head: (B, 3, P, P), (B, 11) -> (B, 9).

    Output: column 0 the gate logit; columns 1-8 (dx, dy) per corner TL, TR, BR, BL, patch
    pixels divided by :attr:`RefineConfig.side`.
    """

    def __init__(self, cfg: RefineConfig = RefineConfig()) -> None:
        super().__init__()
        if cfg.patch % 8 or not 0 < cfg.margin < cfg.patch // 2:
            raise ValueError(f"patch must be a multiple of 8 with 0 < margin < patch/2: {cfg}")
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
        self.hidden = nn.Sequential(nn.Linear(c3 * cells + NUM_GEOM, cfg.hidden), nn.ReLU())
        self.out = nn.Linear(cfg.hidden, 9)

    def forward(self, x: torch.Tensor, geom: torch.Tensor) -> torch.Tensor:
        f = torch.cat([self.features(x).flatten(1), geom.to(x.dtype)], dim=1)
        return self.out(self.hidden(f))


def square(cfg: RefineConfig) -> np.ndarray:
    """(4, 2) where a candidate's corners TL, TR, BR, BL land in the patch (pixel centres)."""
    lo, hi = cfg.margin - 0.5, cfg.patch - cfg.margin - 0.5
    return np.array([[lo, lo], [hi, lo], [hi, hi], [lo, hi]], np.float64)


def homographies(quads: np.ndarray, cfg: RefineConfig) -> np.ndarray:
    """(N, 3, 3) homographies from camera pixels to the patch, one per (4, 2) candidate.

    Args:
        quads: (N, 4, 2) candidate corners, camera pixels, TL, TR, BR, BL.
    """
    dst = square(cfg).astype(np.float32)
    out = np.empty((len(quads), 3, 3))
    for i, q in enumerate(np.asarray(quads, np.float32)):
        out[i] = cv2.getPerspectiveTransform(q, dst)
    return out


def transform(h: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """Apply (N, 3, 3) homographies to (N, K, 2) points."""
    p = np.concatenate([pts, np.ones(pts.shape[:-1] + (1,))], axis=-1) @ np.swapaxes(h, 1, 2)
    with np.errstate(divide="ignore", invalid="ignore"):
        return p[..., :2] / p[..., 2:]


def extract(image: np.ndarray, h: np.ndarray, cfg: RefineConfig) -> np.ndarray:
    """(N, P, P, 3) uint8 patches of ``image`` (H, W, 3) under (N, 3, 3) homographies (black
    outside the image)."""
    out = np.empty((len(h), cfg.patch, cfg.patch, 3), np.uint8)
    for i, m in enumerate(h):
        out[i] = cv2.warpPerspective(
            image, m, (cfg.patch, cfg.patch), flags=cv2.INTER_LINEAR,
            borderMode=cv2.BORDER_CONSTANT, borderValue=0,
        )  # fmt: skip
    return out


def usable(quads: np.ndarray, min_side_px: float = 4.0) -> np.ndarray:
    """(N,) bool: candidates whose quadrilateral is finite, convex, correctly ordered (clockwise
    in the image, y down) and not tiny, so that their homography is well defined."""
    q = np.asarray(quads, float)
    e = np.roll(q, -1, axis=1) - q  # (N, 4, 2) edges
    cross = e[..., 0] * np.roll(e, -1, axis=1)[..., 1] - e[..., 1] * np.roll(e, -1, axis=1)[..., 0]
    with np.errstate(invalid="ignore"):
        big = mean_sides(q) >= min_side_px
        return np.isfinite(q).all(axis=(1, 2)) & (cross > 0).all(axis=1) & big


def offsets_to_corners(h: np.ndarray, offsets: np.ndarray, cfg: RefineConfig) -> np.ndarray:
    """Corrected corners in camera pixels: (N, 8) network offsets under (N, 3, 3) homographies
    -> (N, 4, 2)."""
    in_patch = square(cfg)[None] + offsets.reshape(-1, 4, 2) * cfg.side
    return transform(np.linalg.inv(h), in_patch)


def corners_to_offsets(h: np.ndarray, corners: np.ndarray, cfg: RefineConfig) -> np.ndarray:
    """The network's targets: (N, 4, 2) true corners, camera pixels -> (N, 8) offsets."""
    return ((transform(h, corners) - square(cfg)[None]) / cfg.side).reshape(-1, 8)


def to_tensor(patches: np.ndarray) -> torch.Tensor:
    """(N, P, P, 3) uint8 -> (N, 3, P, P) float32 in [0, 1]."""
    return torch.from_numpy(patches).permute(0, 3, 1, 2).float().div_(255.0)


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


def refine(
    net: nn.Module,
    image: np.ndarray,
    gates: list[tuple[np.ndarray, np.ndarray, float]],
    peaks: list[tuple[np.ndarray, np.ndarray]],
    cfg: RefineConfig,
    nms_iou: float = 0.5,
    dtype: torch.dtype = torch.float32,
) -> list[tuple[np.ndarray, np.ndarray, float]]:
    """Verify and correct one image's candidate gates.

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
    from icarus_vision.gate_detect.cnn.decode import quad_iou

    # the refiner's probability is at most 1: a candidate scored below the threshold by the first
    # stage cannot pass, and is not looked at
    gates = [g for g in gates if g[2] >= cfg.threshold]
    if not gates:
        return []
    quads = np.array([g[0] for g in gates], np.float64)
    ok = usable(quads)
    quads, geom = quads[ok], geometry(quads[ok], stage_scores(gates)[ok], image.shape[1::-1])
    if not len(quads):
        return []
    h = homographies(quads, cfg)
    with torch.inference_mode():
        x = to_tensor(extract(image, h, cfg)).to(dtype)
        out = net(x, torch.from_numpy(geom).to(dtype)).float().numpy()
    prob = 1.0 / (1.0 + np.exp(-out[:, 0]))
    score = prob * np.array([g[2] for g in gates])[ok]
    keep = np.flatnonzero(score >= cfg.threshold)
    if not len(keep):
        return []
    keep = keep[np.argsort(-score[keep], kind="stable")]
    corners = offsets_to_corners(h[keep], out[keep, 1:], cfg)
    corners, snapped = snap_to_peaks(corners, peaks, cfg)
    found: list[tuple[np.ndarray, np.ndarray, float]] = []
    for c, s, p, sc in zip(corners, snapped, prob[keep], score[keep], strict=True):
        if not np.isfinite(c).all() or any(quad_iou(c, f[0]) > nms_iou for f in found):
            continue
        found.append((c, np.where(s > 0, s, p), float(sc)))
    return found
