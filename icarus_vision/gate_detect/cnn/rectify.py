"""Rectifying a candidate gate: the homography that maps its corners onto a square in a small
patch, the patch itself, and corners between the patch and the camera image.

The refiner (``refine.py``) reads these patches. Everything here is pure geometry on (N, ...)
arrays of a frame's candidates, camera pixels (u, v) and corner order TL, TR, BR, BL throughout.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import cv2
import numpy as np
import torch

from icarus_vision.gate_detect.base import FLIP_ORDER
from icarus_vision.gate_detect.cnn.model import to_float
from icarus_vision.gate_detect.metrics import NEXT_CORNER

if TYPE_CHECKING:
    from icarus_vision.gate_detect.cnn.refine import RefineConfig


def square(cfg: RefineConfig) -> np.ndarray:
    """(4, 2) where a candidate's corners TL, TR, BR, BL land in the patch (pixel centres)."""
    lo, hi = cfg.margin - 0.5, cfg.patch - cfg.margin - 0.5
    return np.array([[lo, lo], [hi, lo], [hi, hi], [lo, hi]], np.float64)


def homographies(quads: np.ndarray, cfg: RefineConfig) -> np.ndarray:
    """(N, 3, 3) homographies from camera pixels to the patch, one per (4, 2) candidate.

    Args:
        quads: (N, 4, 2) candidate corners, camera pixels, TL, TR, BR, BL.
    """
    return perspective(quads, square(cfg))


def patch_to_image(quads: np.ndarray, cfg: RefineConfig) -> np.ndarray:
    """(N, 3, 3) inverses of :func:`homographies`: from the patch back to camera pixels
    (computed as such: cheaper than inverting them)."""
    return perspective(square(cfg), quads)


def perspective(src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """(N, 3, 3) homographies taking (4, 2) ``src`` corners onto ``dst`` corners, either side
    (N, 4, 2) or one (4, 2) shared by all (OpenCV, in float32)."""
    src, dst = np.asarray(src, np.float32), np.asarray(dst, np.float32)
    n = len(src) if src.ndim == 3 else len(dst) if dst.ndim == 3 else 1
    src = np.ascontiguousarray(np.broadcast_to(src, (n, 4, 2)))
    dst = np.ascontiguousarray(np.broadcast_to(dst, (n, 4, 2)))
    out = np.empty((n, 3, 3))
    for i in range(n):
        out[i] = cv2.getPerspectiveTransform(src[i], dst[i])
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
    e = q[:, NEXT_CORNER] - q  # (N, 4, 2) edges
    f = e[:, NEXT_CORNER]
    cross = e[..., 0] * f[..., 1] - e[..., 1] * f[..., 0]
    with np.errstate(invalid="ignore"):
        big = np.sqrt((e * e).sum(axis=-1)).mean(axis=-1) >= min_side_px  # mean_sides
        return np.isfinite(q).all(axis=(1, 2)) & (cross > 0).all(axis=1) & big


def offsets_to_corners(
    h: np.ndarray,
    offsets: np.ndarray,
    cfg: RefineConfig,
    mirrored: np.ndarray | None = None,
    back: np.ndarray | None = None,
) -> np.ndarray:
    """Corrected corners in camera pixels: (N, 8) network offsets under (N, 3, 3) homographies
    -> (N, 4, 2).

    Args:
        mirrored: also (N, 8) offsets read from each patch mirrored left to right (corner order
            swapped: :func:`mirrored`); then the mean of both readings' corners, in the image.
        back: the homographies' inverses (patch to camera: :func:`patch_to_image`), if known;
            ``h`` is then not used.
    """
    back = np.linalg.inv(h) if back is None else back
    in_patch = square(cfg)[None] + offsets.reshape(-1, 4, 2) * cfg.side
    if mirrored is None:
        return transform(back, in_patch)
    # mirroring the patch is x -> P - 1 - x (the square is symmetric: lo + hi = P - 1)
    flip = (square(cfg)[None] + mirrored.reshape(-1, 4, 2) * cfg.side)[:, FLIP_ORDER]
    flip[..., 0] = cfg.patch - 1 - flip[..., 0]
    both = transform(back, np.concatenate([in_patch, flip], axis=1))
    return 0.5 * (both[:, :4] + both[:, 4:])


def corners_to_offsets(h: np.ndarray, corners: np.ndarray, cfg: RefineConfig) -> np.ndarray:
    """The network's targets: (N, 4, 2) true corners, camera pixels -> (N, 8) offsets."""
    return ((transform(h, corners) - square(cfg)[None]) / cfg.side).reshape(-1, 8)


def to_tensor(patches: np.ndarray) -> torch.Tensor:
    """(N, P, P, 3) uint8 -> (N, 3, P, P) float32 in [0, 1] (channels-last memory: no copy)."""
    return torch.from_numpy(patches).permute(0, 3, 1, 2).float().div_(255.0)


def network_patches(patches: np.ndarray, mirror: bool = False) -> np.ndarray:
    """(N, P, P, 3) uint8 -> (N, 3, P, P) float32 in [0, 1], contiguous (what ONNX Runtime
    reads, in one pass); with ``mirror``, (2N, ...): the patches, then each mirrored left to
    right. The values are :func:`to_tensor`'s."""
    n, p = len(patches), patches.shape[1]
    out = np.empty((2 * n if mirror else n, 3, p, p), np.float32)
    to_float(patches, out[:n])
    if mirror:
        out[n:] = out[:n, :, :, ::-1]
    return out


def mirrored(quads: np.ndarray, width: int) -> tuple[np.ndarray, np.ndarray]:
    """The mirrored reading of (N, 4, 2) candidates in a frame ``width`` pixels wide: the corners
    to rectify (the corner order swapped, so the patch comes out mirrored) and where the
    candidate lies in the mirror image (what ``refine.geometry`` is told)."""
    flipped = quads[:, FLIP_ORDER]
    where = flipped.copy()
    where[..., 0] = width - 1 - where[..., 0]
    return flipped, where


def squareness(quads: np.ndarray, image_size: tuple[int, int], hfov_deg: float) -> np.ndarray:
    """(N, 2) how far each (4, 2) quadrilateral is from the image of a square: log of the ratio
    of its two sides' lengths in 3-D, and the cosine of the angle between them (both 0 for a
    square), under a pinhole camera of ``hfov_deg`` with a centred principal point.

    The homography H from the unit square to the quadrilateral is K [r1 r2 t] up to scale, r1
    and r2 the square's two edge directions scaled by its size; a square has |r1| = |r2| and
    r1 . r2 = 0. Gate-like frames that are not square (the dataset's distractors) fail this in
    most views, though rectifying the candidate hides its shape from the patch. A camera whose
    field of view differs from ``hfov_deg`` shifts both values a little (a refiner learns that
    spread, as the training data's fields of view vary).
    """
    w, h = image_size
    f = 0.5 * w / math.tan(math.radians(hfov_deg) / 2.0)
    k_inv = np.array([[1.0 / f, 0.0, -(w - 1) / (2.0 * f)],
                      [0.0, 1.0 / f, -(h - 1) / (2.0 * f)], [0.0, 0.0, 1.0]])  # fmt: skip
    r = k_inv @ perspective(_UNIT_SQUARE, quads)[:, :, :2]  # (N, 3, 2): r1, r2
    gram = np.swapaxes(r, 1, 2) @ r  # (N, 2, 2): |r1|^2, r1 . r2; r1 . r2, |r2|^2
    with np.errstate(divide="ignore", invalid="ignore"):
        aspect = np.clip(0.5 * np.log(gram[:, 0, 0] / gram[:, 1, 1]), -3.0, 3.0)
        cos = np.clip(gram[:, 0, 1] / np.sqrt(gram[:, 0, 0] * gram[:, 1, 1]), -1.0, 1.0)
    out = np.stack([aspect, cos], axis=1)
    return np.where(np.isnan(out), 0.0, out)


_UNIT_SQUARE = np.array([[-0.5, -0.5], [0.5, -0.5], [0.5, 0.5], [-0.5, 0.5]])
"""A unit square about the origin, corners TL, TR, BR, BL."""
