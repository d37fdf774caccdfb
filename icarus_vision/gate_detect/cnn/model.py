"""The corner network: a small encoder-decoder that predicts gate centres and corners at stride 4.

Input: an RGB frame resized to ``ModelConfig.input_size``, scaled to [0, 1]: by default the full
320x240 frame, which a stride-2 stem reduces before the encoder (``stem_width``); without a stem,
usually half the frame (160x120). Output, on a grid of ``stride`` camera pixels per cell (80x60
cells for a 320x240 frame either way):

* channel 0: gate-centre heatmap (logits; the centre is the mean of the four opening corners),
* channels 1-4: corner heatmaps (logits), one per corner type TL, TR, BR, BL,
* channels 5-6: sub-cell offset (x, y) of a corner relative to the cell's top-left, in cells,
* channels 7-14: the four corners relative to the centre cell, (dx, dy) per corner, in cells / 8.

Grouping corners into gates: ``decode.py``.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import cv2
import numpy as np
import torch
from torch import nn

from icarus_vision.gate_detect.cnn.resize import area_resize
from icarus_vision.render.camera import PAD_VALUE, letterbox_size

NUM_OUT = 15
"""Output channels: centre heatmap, 4 corner heatmaps, 2 offsets, 8 centre-to-corner vectors."""
VECTOR_SCALE = 8.0
"""Centre-to-corner vectors are predicted in units of ``VECTOR_SCALE`` cells."""


@dataclass(frozen=True)
class ModelConfig:
    """Architecture of the corner network (stored as JSON beside the weights)."""

    input_size: tuple[int, int] = (320, 240)
    """Network input (width, height), pixels; frames are resized to it (INTER_AREA)."""
    image_size: tuple[int, int] = (320, 240)
    """Camera frame (width, height) the network was trained for, pixels."""
    widths: tuple[int, int, int, int] = (16, 32, 64, 160)
    """Channels of the four encoder stages (each halves the resolution; the first works at input
    stride 2, or 4 after a stem)."""
    head_width: int = 32
    """Channels of the decoder at the output resolution."""
    stem_width: int = 12
    """Channels of a stride-2 convolution on the input before the encoder (0: no stem; the
    output is then at input stride 2 instead of 4)."""

    @property
    def input_stride(self) -> int:
        """Input pixels per output cell."""
        return 4 if self.stem_width else 2

    @property
    def grid(self) -> tuple[int, int]:
        """Output (width, height), cells."""
        w, h = self.input_size
        return w // self.input_stride, h // self.input_stride

    @property
    def stride(self) -> float:
        """Camera pixels per output cell."""
        return self.input_stride * self.image_size[0] / self.input_size[0]

    def to_dict(self) -> dict:
        return {k: list(v) if isinstance(v, tuple) else v for k, v in asdict(self).items()}

    @classmethod
    def from_dict(cls, d: dict) -> ModelConfig:
        known = {"input_size", "image_size", "widths", "head_width", "stem_width"}
        unknown = set(d) - known
        if unknown:
            raise ValueError(f"unknown model config keys {sorted(unknown)}")
        d = {"stem_width": 0, **d}  # files written before the stem existed had none
        return cls(**{k: tuple(v) if isinstance(v, list) else v for k, v in d.items()})


def network_input(image: np.ndarray, input_size: tuple[int, int]) -> np.ndarray:
    """(H, W, 3) frame as the corner network reads it: letterboxed (padded with grey at the
    right or bottom to the input's aspect ratio, :func:`letterbox_size`, never stretched), then
    resized to ``input_size`` (W, H) with ``INTER_AREA`` (by
    :func:`~icarus_vision.gate_detect.cnn.resize.area_resize`: the same output, faster at 5:4);
    as it is if already that size (training, validation, tuning and the detector all read
    frames through this). Pixel (u, v) of the frame is at (u, v) x input / letterboxed size."""
    if image.shape[1::-1] == tuple(input_size):
        return image
    h, w = image.shape[:2]
    pw, ph = letterbox_size((w, h), input_size)
    if (pw, ph) != (w, h):
        image = cv2.copyMakeBorder(image, 0, ph - h, 0, pw - w, cv2.BORDER_CONSTANT,
                                   value=(PAD_VALUE,) * image.shape[2])  # fmt: skip
    return area_resize(image, input_size)


def to_float(images: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    """(B, H, W, 3) uint8 -> (B, 3, H, W) float32 in [0, 1], contiguous (what ONNX Runtime
    reads; one pass, into ``out`` if given). The values are ``x.float() / 255`` in PyTorch."""
    if out is None:
        out = np.empty((images.shape[0], 3, *images.shape[1:3]), np.float32)
    np.divide(images.transpose(0, 3, 1, 2), np.float32(255.0), out=out, dtype=np.float32)
    return out


def conv_bn_relu(cin: int, cout: int, stride: int = 1, dilation: int = 1) -> nn.Sequential:
    """3x3 convolution (no bias), batch norm, ReLU."""
    return nn.Sequential(
        nn.Conv2d(cin, cout, 3, stride, padding=dilation, dilation=dilation, bias=False),
        nn.BatchNorm2d(cout),
        nn.ReLU(inplace=True),
    )


class CornerNet(nn.Module):
    """Optional stem, encoder (4 stages of stride 2) with a dilated context block at the last,
    FPN-style decoder back to the first stage's resolution.

    Args:
        cfg: the architecture.

    Shapes: (B, 3, H, W) float in [0, 1] -> (B, 15, H/s, W/s), s = ``cfg.input_stride`` (see
    the module docstring).
    """

    def __init__(self, cfg: ModelConfig = ModelConfig()) -> None:
        super().__init__()
        c1, c2, c3, c4 = cfg.widths
        h = cfg.head_width
        self.cfg = cfg
        self.stem = conv_bn_relu(3, cfg.stem_width, 2) if cfg.stem_width else nn.Identity()
        self.enc1 = nn.Sequential(conv_bn_relu(cfg.stem_width or 3, c1, 2), conv_bn_relu(c1, c1))
        self.enc2 = nn.Sequential(conv_bn_relu(c1, c2, 2), conv_bn_relu(c2, c2))
        self.enc3 = nn.Sequential(conv_bn_relu(c2, c3, 2), conv_bn_relu(c3, c3))
        self.enc4 = nn.Sequential(
            conv_bn_relu(c3, c4, 2),
            conv_bn_relu(c4, c4, dilation=2),
            conv_bn_relu(c4, c4, dilation=4),
        )
        self.lat3 = nn.Conv2d(c3, c4, 1)
        self.up3 = conv_bn_relu(c4, c3)
        self.lat2 = nn.Conv2d(c2, c3, 1)
        self.up2 = conv_bn_relu(c3, h)
        self.lat1 = nn.Conv2d(c1, h, 1)
        self.up1 = conv_bn_relu(h, h)
        self.out = nn.Conv2d(h, NUM_OUT, 1)
        with torch.no_grad():  # heatmaps start near 0.01 (focal-loss practice)
            self.out.bias.zero_()
            self.out.bias[:5].fill_(-4.6)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        f1 = self.enc1(self.stem(x))
        f2 = self.enc2(f1)
        f3 = self.enc3(f2)
        f4 = self.enc4(f3)
        up = nn.functional.interpolate
        y = self.up3(self.lat3(f3) + up(f4, size=f3.shape[-2:], mode="nearest"))
        y = self.up2(self.lat2(f2) + up(y, size=f2.shape[-2:], mode="nearest"))
        y = self.up1(self.lat1(f1) + up(y, size=f1.shape[-2:], mode="nearest"))
        return self.out(y)
