"""Training targets of the corner network and the decoding of its output into gate detections.

Coordinates: a camera pixel (u, v) has its centre at integer values (OpenCV); the continuous
coordinate ``c = u + 0.5`` puts the image's left edge at 0. On the output grid (``stride`` camera
pixels per cell) a point lies at ``g = c / stride``: in cell ``floor(g)`` with sub-cell offset
``g - floor(g)``. Targets are built in grid units from continuous coordinates.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
import torch

from icarus_vision.gate_detect.cnn.model import VECTOR_SCALE

CENTRE, CORNERS, OFFSET, VECTORS = 0, slice(1, 5), slice(5, 7), slice(7, 15)


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
    peak whose corners the corner maps do not confirm is usually a false alarm)."""
    nms_iou: float = 0.5
    """A gate whose opening overlaps a better-scored one's by more than this (intersection over
    union) is the same gate found twice, and dropped."""


def _gaussian(hm: np.ndarray, cx: int, cy: int, sigma: float) -> None:
    """Draw a Gaussian of peak 1 at cell (cx, cy) into ``hm`` (H, W) with element-wise max."""
    h, w = hm.shape
    r = int(np.ceil(3 * sigma))
    x0, x1, y0, y1 = max(cx - r, 0), min(cx + r + 1, w), max(cy - r, 0), min(cy + r + 1, h)
    if x0 >= x1 or y0 >= y1:
        return
    xs = np.arange(x0, x1) - cx
    ys = np.arange(y0, y1) - cy
    g = np.exp(-(xs[None, :] ** 2 + ys[:, None] ** 2) / (2 * sigma**2))
    np.maximum(hm[y0:y1, x0:x1], g, out=hm[y0:y1, x0:x1])


def encode_targets(
    gates: list[tuple[np.ndarray, np.ndarray]], grid_w: int, grid_h: int
) -> tuple[np.ndarray, np.ndarray]:
    """Targets of one image.

    Args:
        gates: per gate ``(g, vis)``: g (4, 2) corners in grid units (TL, TR, BR, BL; NaN when
            unknown), vis (4,) COCO visibility after augmentation (2 visible, 1 hidden, 0 outside).
        grid_w, grid_h: output grid size, cells.

    Returns:
        target: (15, H, W) float32 (channel layout of the network output).
        weight: (3, H, W) float32 regression weights: offsets, vectors, spare (zeros).
    """
    t = np.zeros((15, grid_h, grid_w), np.float32)
    wt = np.zeros((3, grid_h, grid_w), np.float32)
    for g, vis in gates:
        finite = np.isfinite(g).all(axis=1)
        side = np.nan
        if finite.all():
            side = float(np.linalg.norm(g - np.roll(g, -1, axis=0), axis=1).mean())
        for k in range(4):
            if vis[k] != 2 or not finite[k]:
                continue
            cx, cy = int(np.floor(g[k, 0])), int(np.floor(g[k, 1]))
            if not (0 <= cx < grid_w and 0 <= cy < grid_h):
                continue
            sigma = float(np.clip(0.08 * side, 0.6, 1.5)) if np.isfinite(side) else 0.6
            _gaussian(t[1 + k], cx, cy, sigma)
            for dy in (-1, 0, 1):
                for dx in (-1, 0, 1):
                    x, y = cx + dx, cy + dy
                    w = 1.0 if dx == dy == 0 else 0.5
                    if 0 <= x < grid_w and 0 <= y < grid_h and w > wt[0, y, x]:
                        t[OFFSET, y, x] = g[k] - (x, y)
                        wt[0, y, x] = w
        if not finite.all() or np.count_nonzero(vis == 2) < 2:
            continue
        c = g.mean(axis=0)
        cx, cy = int(np.floor(c[0])), int(np.floor(c[1]))
        if not (0 <= cx < grid_w and 0 <= cy < grid_h):
            continue
        _gaussian(t[0], cx, cy, float(np.clip(0.12 * side, 0.7, 4.0)))
        for dy in (-1, 0, 1):
            for dx in (-1, 0, 1):
                x, y = cx + dx, cy + dy
                w = 1.0 if dx == dy == 0 else 0.3
                if 0 <= x < grid_w and 0 <= y < grid_h and w > wt[1, y, x]:
                    t[VECTORS, y, x] = ((g - (x, y)) / VECTOR_SCALE).reshape(-1)
                    wt[1, y, x] = w
    return t, wt


def focal_loss(logits: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """CenterNet's penalty-reduced focal loss, summed, divided by the number of peaks."""
    p = torch.sigmoid(logits).clamp(1e-4, 1 - 1e-4)
    pos = target.eq(1).float()
    neg_w = (1 - target) ** 4
    pos_loss = torch.log(p) * (1 - p) ** 2 * pos
    neg_loss = torch.log(1 - p) * p**2 * neg_w * (1 - pos)
    return -(pos_loss.sum() + neg_loss.sum()) / pos.sum().clamp(min=1.0)


def detection_loss(out: torch.Tensor, target: torch.Tensor, weight: torch.Tensor) -> dict:
    """Loss terms of a batch: (B, 15, H, W) output and target, (B, 3, H, W) weights."""
    centre = focal_loss(out[:, CENTRE], target[:, CENTRE])
    corners = focal_loss(out[:, CORNERS], target[:, CORNERS])
    w_off, w_vec = weight[:, 0:1], weight[:, 1:2]
    offset = (w_off * (out[:, OFFSET] - target[:, OFFSET]).abs()).sum() / w_off.sum().clamp(min=1)
    vectors = (w_vec * (out[:, VECTORS] - target[:, VECTORS]).abs()).sum()
    vectors = vectors / (4 * w_vec.sum()).clamp(min=1)
    total = centre + corners + offset + 4.0 * vectors
    return {
        "loss": total,
        "centre": centre,
        "corners": corners,
        "offset": offset,
        "vectors": vectors,
    }


_KERNEL = np.ones((3, 3), np.uint8)


def _peaks(heat: np.ndarray, threshold: float) -> np.ndarray:
    """(H, W) probabilities -> boolean local maxima (3x3) at or above ``threshold``."""
    return (heat == cv2.dilate(heat, _KERNEL)) & (heat >= threshold)


def decode(
    out: torch.Tensor, cfg: DecodeConfig, scale: tuple[float, float]
) -> list[tuple[np.ndarray, np.ndarray, float]]:
    """Gates from one image's network output.

    Args:
        out: (15, H, W) raw network output.
        cfg: thresholds.
        scale: (sx, sy) camera pixels per grid cell.

    Returns:
        per gate ``(corners (4, 2) pixels TL, TR, BR, BL, corner_scores (4,), score)``, best first.
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
    gates = []
    for i in order:
        cx, cy = cxs[i], cys[i]
        g = np.array([cx, cy], float) + VECTOR_SCALE * reg[2:, cy, cx].reshape(4, 2)
        side = float(np.linalg.norm(g - np.roll(g, -1, axis=0), axis=1).mean())
        radius = max(1.5, cfg.snap_radius * side)
        scores = np.zeros(4)
        for k in range(4):
            pos, val = cand[k]
            if len(pos):
                d = np.linalg.norm(pos - g[k], axis=1)
                j = int(np.argmin(d))
                if d[j] <= radius:
                    g[k], scores[k] = pos[j], val[j]
        if np.count_nonzero(scores) < cfg.min_snapped:
            continue
        corners = g * np.asarray(scale) - 0.5
        score = float(heat_np[0, cy, cx])
        if any(quad_iou(corners, c) > cfg.nms_iou for c, _, _ in gates):
            continue
        gates.append((corners, scores, score))
    return gates


def quad_iou(a: np.ndarray, b: np.ndarray) -> float:
    """Intersection over union of two (4, 2) quadrilaterals (their convex hulls), in [0, 1]."""
    ha = cv2.convexHull(np.asarray(a, np.float32))
    hb = cv2.convexHull(np.asarray(b, np.float32))
    inter, _ = cv2.intersectConvexConvex(ha, hb)
    union = cv2.contourArea(ha) + cv2.contourArea(hb) - inter
    return min(float(inter / union), 1.0) if union > 0 else 0.0
