"""Training targets and loss of the corner network (decoding its output: ``decode.py``).

Coordinates: a camera pixel (u, v) has its centre at integer values (OpenCV); the continuous
coordinate ``c = u + 0.5`` puts the image's left edge at 0. On the output grid (``stride`` camera
pixels per cell) a point lies at ``g = c / stride``: in cell ``floor(g)`` with sub-cell offset
``g - floor(g)``. Targets are built in grid units from continuous coordinates.
"""

from __future__ import annotations

import numpy as np
import torch

from icarus_vision.gate_detect.cnn.model import VECTOR_SCALE
from icarus_vision.gate_detect.metrics import mean_side

CENTRE, CORNERS, OFFSET, VECTORS = 0, slice(1, 5), slice(5, 7), slice(7, 15)
IGNORE = 2
"""Channel of the ignore map in the weights."""


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
    gates: list[tuple[np.ndarray, np.ndarray]], grid_w: int, grid_h: int, ignore_below: float = 0.0
) -> tuple[np.ndarray, np.ndarray]:
    """Targets of one image.

    Args:
        gates: per gate ``(g, vis)``: g (4, 2) corners in grid units (TL, TR, BR, BL; NaN when
            unknown), vis (4,) COCO visibility after augmentation (2 visible, 1 hidden, 0 outside).
        grid_w, grid_h: output grid size, cells.
        ignore_below: a gate whose opening's mean side is shorter than this (cells) is no target:
            its bounding box, grown by a cell, is marked in the ignore map instead, where the
            heatmap loss neither asks for nor penalises a peak.

    Returns:
        target: (15, H, W) float32 (channel layout of the network output).
        weight: (3, H, W) float32: offset and vector regression weights, ignore map (0 or 1).
    """
    t = np.zeros((15, grid_h, grid_w), np.float32)
    wt = np.zeros((3, grid_h, grid_w), np.float32)
    for g, vis in gates:
        finite = np.isfinite(g).all(axis=1)
        side = np.nan
        if finite.all():
            side = mean_side(g)
            if side < ignore_below:
                x0, y0 = np.floor(g.min(axis=0)).astype(int) - 1
                x1, y1 = np.floor(g.max(axis=0)).astype(int) + 2
                wt[IGNORE, max(y0, 0) : max(y1, 0), max(x0, 0) : max(x1, 0)] = 1.0
                continue
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


def focal_loss(
    logits: torch.Tensor, target: torch.Tensor, ignore: torch.Tensor | None = None
) -> torch.Tensor:
    """CenterNet's penalty-reduced focal loss, summed, divided by the number of peaks.

    ``ignore`` (broadcastable to ``target``, 1 = ignored) removes the penalty of a peak there."""
    p = torch.sigmoid(logits).clamp(1e-4, 1 - 1e-4)
    pos = target.eq(1).float()
    neg_w = (1 - target) ** 4
    if ignore is not None:
        neg_w = neg_w * (1 - ignore)
    pos_loss = torch.log(p) * (1 - p) ** 2 * pos
    neg_loss = torch.log(1 - p) * p**2 * neg_w * (1 - pos)
    return -(pos_loss.sum() + neg_loss.sum()) / pos.sum().clamp(min=1.0)


def detection_loss(out: torch.Tensor, target: torch.Tensor, weight: torch.Tensor) -> dict:
    """Loss terms of a batch: (B, 15, H, W) output and target, (B, 3, H, W) weights."""
    ignore = weight[:, IGNORE : IGNORE + 1]
    centre = focal_loss(out[:, CENTRE], target[:, CENTRE], ignore[:, 0])
    corners = focal_loss(out[:, CORNERS], target[:, CORNERS], ignore)
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
