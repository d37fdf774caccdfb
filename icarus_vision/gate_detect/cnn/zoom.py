"""The third stage: each corner of a detected gate read again, zoomed in.

The refiner (``refine.py``) reads a whole candidate in one small patch: on a gate 100 px across,
one patch pixel spans about three camera pixels, and its corners can stay several pixels off. The
zoom stage cuts around each corner of every reported gate at least ``min_side_px`` across a
``patch`` x ``patch`` patch that covers ``extent`` of the gate's side on each side of the
corner. Each patch is rectified by the gate's own homography and turned so that every corner
looks like a top-left one (the gate's opening towards the patch's bottom right, the frame
towards its top left); a small network says where the corner is in it. All corners of a frame
go through the network in one call.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
import torch
from torch import nn

from icarus_vision.gate_detect.cnn.model import to_float
from icarus_vision.gate_detect.cnn.rectify import extract, perspective, transform, usable
from icarus_vision.gate_detect.cnn.runtime import run_network
from icarus_vision.gate_detect.metrics import mean_sides

ROLLS = np.array([[(i + k) % 4 for k in range(4)] for i in range(4)])
"""``quad[ROLLS[i]]`` starts at corner i and keeps the order around the gate."""


@dataclass(frozen=True)
class ZoomConfig:
    """Architecture of the zoom stage and where it is used (stored in ``detector.json``)."""

    patch: int = 32
    """Side of a corner's patch, pixels (a multiple of 8)."""
    extent: float = 0.25
    """The patch spans this fraction of the gate's side on each side of the corner."""
    widths: tuple[int, int, int, int] = (16, 32, 48, 64)
    """Channels at full, half, quarter and eighth patch resolution."""
    hidden: int = 128
    """Units of the fully connected layer."""
    min_side_px: float = 20.0
    """Gates whose opening's mean side is under this (pixels) keep the refiner's corners."""
    mirror: bool = False
    """Also read each patch mirrored about its diagonal (the same corner seen from the other
    edge: the output's two coordinates swap) and average the two readings (test-time
    augmentation: twice the network's work)."""

    @property
    def scale(self) -> float:
        """Patch pixels per gate side."""
        return self.patch / (2.0 * self.extent)

    def to_dict(self) -> dict:
        return {k: list(v) if isinstance(v, tuple) else v for k, v in asdict(self).items()}

    @classmethod
    def from_dict(cls, d: dict) -> ZoomConfig:
        return cls(**{k: tuple(v) if isinstance(v, list) else v for k, v in d.items()})


def _conv(c_in: int, c_out: int, stride: int) -> nn.Sequential:
    return nn.Sequential(
        nn.Conv2d(c_in, c_out, 3, stride, 1, bias=False),
        nn.BatchNorm2d(c_out),
        nn.ReLU(inplace=True),
    )


class ZoomNet(nn.Module):
    """(N, 3, P, P) corner patches in [0, 1] -> (N, 2): where the corner is, relative to the
    patch centre, in half patches (:func:`to_corners`)."""

    def __init__(self, cfg: ZoomConfig = ZoomConfig()) -> None:
        super().__init__()
        if cfg.patch % 8:
            raise ValueError(f"patch must be a multiple of 8, got {cfg.patch}")
        self.cfg = cfg
        w = cfg.widths
        self.features = nn.Sequential(
            _conv(3, w[0], 1), _conv(w[0], w[1], 2), _conv(w[1], w[1], 1),
            _conv(w[1], w[2], 2), _conv(w[2], w[2], 1), _conv(w[2], w[3], 2), _conv(w[3], w[3], 1),
        )  # fmt: skip
        cells = (cfg.patch // 8) ** 2
        self.head = nn.Sequential(
            nn.Flatten(), nn.Linear(cells * w[3], cfg.hidden), nn.ReLU(inplace=True),
            nn.Linear(cfg.hidden, 2),
        )  # fmt: skip

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.head(self.features((x - 0.5) * 4.0))


def square(cfg: ZoomConfig) -> np.ndarray:
    """(4, 2) where a gate's corners land in the patch of its first corner (pixel centres): that
    corner at the patch centre, the next one ``1 / extent`` half patches to the right."""
    c, s = cfg.patch / 2.0 - 0.5, cfg.scale
    return np.array([[c, c], [c + s, c], [c + s, c + s], [c, c + s]])


def rolled(quads: np.ndarray) -> np.ndarray:
    """(N, 4, 2) quadrilaterals -> (4N, 4, 2): each one four times, starting at each corner."""
    return quads[:, ROLLS].reshape(-1, 4, 2)


def homographies(quads: np.ndarray, cfg: ZoomConfig) -> tuple[np.ndarray, np.ndarray]:
    """Camera-to-patch and patch-to-camera homographies of the (N, 4, 2) gates' corners: each
    (4N, 3, 3), gate by gate, corners TL, TR, BR, BL."""
    r = rolled(np.asarray(quads, float))
    return perspective(r, square(cfg)), perspective(square(cfg), r)


def to_targets(h: np.ndarray, corners: np.ndarray, cfg: ZoomConfig) -> np.ndarray:
    """The network's targets: (4N, 2) true corners, camera pixels, under (4N, 3, 3)
    camera-to-patch homographies -> (4N, 2) half patches from the centre."""
    half = cfg.patch / 2.0
    return (transform(h, corners[:, None])[:, 0] - (half - 0.5)) / half


def to_corners(back: np.ndarray, out: np.ndarray, cfg: ZoomConfig) -> np.ndarray:
    """(4N, 2) network outputs under (4N, 3, 3) patch-to-camera homographies -> (4N, 2)
    camera pixels."""
    half = cfg.patch / 2.0
    return transform(back, (out * half + (half - 0.5))[:, None])[:, 0]


def zoomable(quads: np.ndarray, cfg: ZoomConfig) -> np.ndarray:
    """(N,) bool: gates the stage reads (well formed and at least ``min_side_px``)."""
    q = np.asarray(quads, float).reshape(-1, 4, 2)
    return usable(q) & (mean_sides(q) >= cfg.min_side_px)


def sharpen(net, image: np.ndarray, quads: np.ndarray, cfg: ZoomConfig) -> np.ndarray:
    """The (N, 4, 2) gates' corners read again by the zoom stage (those it does not read, as
    they are).

    Args:
        net: a :class:`ZoomNet` (eval mode) or a network with a numpy ``run``
            (:class:`~icarus_vision.gate_detect.cnn.runtime.OnnxRuntimeNet`).
        image: (H, W, 3) uint8 RGB camera frame.
        quads: (N, 4, 2) corners, camera pixels, TL, TR, BR, BL.
    """
    out = np.array(quads, float).reshape(-1, 4, 2)
    use = zoomable(out, cfg)
    if not use.any():
        return out
    h, back = homographies(out[use], cfg)
    y = read(net, to_float(extract(image, h, cfg)), cfg.mirror)
    out[use] = to_corners(back, y, cfg).reshape(-1, 4, 2)
    return out


def read(net, x: np.ndarray, mirror: bool) -> np.ndarray:
    """(N, 2) float64 network outputs on (N, 3, P, P) float32 patches in [0, 1]; with
    ``mirror``, each patch is also read mirrored about its diagonal (in the same call) and the
    two readings averaged (:func:`mirror_mean`)."""
    if mirror:
        x = np.concatenate([x, x.transpose(0, 1, 3, 2)])
    y = run_network(net, x).astype(np.float64)
    return mirror_mean(y) if mirror else y


def mirror_mean(y: np.ndarray) -> np.ndarray:
    """(2M, 2) outputs on M patches, then on the same patches mirrored about their diagonal ->
    (M, 2): the mean of both readings."""
    m = len(y) // 2
    return 0.5 * (y[:m] + y[m:, ::-1])
