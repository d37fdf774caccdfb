"""The fourth stage: a small MLP that scores each refined candidate from its numbers alone.

The refiner's probability times the first stage's score ranks candidates; the squareness check
then drops some. Neither looks at what the later stages measured: how far the zoom stage moved
the corners, how square the opening is in 3-D on either set of corners, how near the frame's edge
it lies. The rescorer reads those twelve numbers (:data:`FEATURES`) per candidate and returns the
probability that the candidate, as the zoom stage leaves it, matches a counted gate under
eval-detector's rule (``gate_detect/metrics.py``). The detector then keeps candidates scoring at
least ``RescoreConfig.threshold``, best first, as before. Measured on val: the same precision with
more recall and PCK@5px (docs/detector-history.md).

It is trained on a detector's candidates on images none of its networks saw
(``icarus-vision train-rescorer``), costs a few microseconds a frame and is stored as
``rescore.safetensors`` plus a ``rescore`` section in ``detector.json`` (tensors only).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
import torch
from torch import nn

from icarus_vision.gate_detect.cnn.rectify import squareness
from icarus_vision.gate_detect.cnn.refine import NOMINAL_HFOV_DEG
from icarus_vision.gate_detect.metrics import evaluable, mean_sides

FEATURES = (
    "logit_refiner", "logit_stage", "log_side", "skew_zoom", "cos_zoom", "skew_refined",
    "cos_refined", "zoom_shift_mean", "zoom_shift_max", "border_px", "border_sides",
    "log_side_ratio",
)  # fmt: skip
"""What the rescorer reads per candidate (:func:`features`), in order."""
PROB_EPS = 1e-4
"""Probabilities are clipped to [eps, 1 - eps] before their logit."""


@dataclass(frozen=True)
class RescoreConfig:
    """The rescorer's architecture and operating point (stored in ``detector.json``)."""

    hidden: tuple[int, ...] = (32, 32)
    """Units of each hidden layer (ReLU)."""
    threshold: float = 0.2
    """Smallest rescored probability of a reported gate."""
    mean: tuple[float, ...] = (0.0,) * len(FEATURES)
    """Per-feature mean of the training candidates (inputs are standardised)."""
    std: tuple[float, ...] = (1.0,) * len(FEATURES)
    """Per-feature standard deviation of the training candidates."""

    def __post_init__(self) -> None:
        if len(self.mean) != len(FEATURES) or len(self.std) != len(FEATURES):
            raise ValueError(f"mean and std need {len(FEATURES)} values each")
        if not all(h >= 1 for h in self.hidden) or not 0.0 <= self.threshold <= 1.0:
            raise ValueError(f"hidden units must be >= 1 and threshold in [0, 1]: {self}")

    def to_dict(self) -> dict:
        return {k: list(v) if isinstance(v, tuple) else v for k, v in asdict(self).items()}

    @classmethod
    def from_dict(cls, d: dict) -> RescoreConfig:
        d = dict(d)
        for k in ("hidden", "mean", "std"):
            if k in d:
                d[k] = tuple(d[k])
        return cls(**d)


class RescoreNet(nn.Module):
    """Standardise, then an MLP to one logit per candidate."""

    def __init__(self, cfg: RescoreConfig = RescoreConfig()) -> None:
        super().__init__()
        self.cfg = cfg
        layers: list[nn.Module] = []
        width = len(FEATURES)
        for h in cfg.hidden:
            layers += [nn.Linear(width, h), nn.ReLU()]
            width = h
        layers.append(nn.Linear(width, 1))
        self.mlp = nn.Sequential(*layers)
        self._numpy: list[tuple[np.ndarray, np.ndarray]] | None = None

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        mean = torch.tensor(self.cfg.mean, dtype=x.dtype)
        std = torch.tensor(self.cfg.std, dtype=x.dtype)
        return self.mlp((x - mean) / std).squeeze(-1)

    def probabilities(self, x: np.ndarray) -> np.ndarray:
        """(N,) probabilities of (N, len(FEATURES)) features, in numpy (a frame's few
        candidates: torch's per-call overhead would be most of the time)."""
        if self._numpy is None or self.training:
            lin = [m for m in self.mlp if isinstance(m, nn.Linear)]
            self._numpy = [(m.weight.detach().double().numpy().T.copy(),
                            m.bias.detach().double().numpy().copy()) for m in lin]  # fmt: skip
        h = (np.asarray(x, np.float64) - np.array(self.cfg.mean)) / np.array(self.cfg.std)
        for i, (w, b) in enumerate(self._numpy):
            h = h @ w + b
            if i < len(self._numpy) - 1:
                h = np.maximum(h, 0.0)
        return 1.0 / (1.0 + np.exp(-h[:, 0]))

    def load_state_dict(self, *args, **kwargs):  # the numpy copy follows new weights
        self._numpy = None
        return super().load_state_dict(*args, **kwargs)


def _logit(p: np.ndarray) -> np.ndarray:
    p = np.clip(p, PROB_EPS, 1.0 - PROB_EPS)
    return np.log(p / (1.0 - p))


def features(
    prob: np.ndarray,
    stage: np.ndarray,
    refined: np.ndarray,
    zoomed: np.ndarray,
    image_size: tuple[int, int],
) -> np.ndarray:
    """(N, len(FEATURES)) what the rescorer reads about N candidates.

    Args:
        prob: (N,) the refiner's gate probabilities.
        stage: (N,) the first stage's scores.
        refined: (N, 4, 2) the refiner's corners, camera pixels.
        zoomed: (N, 4, 2) the same after the zoom stage (as refined where it does not read).
        image_size: (W, H) of the frame.
    """
    w, h = image_size
    sq_z = squareness(zoomed, image_size, NOMINAL_HFOV_DEG)
    sq_r = squareness(refined, image_size, NOMINAL_HFOV_DEG)
    side = np.maximum(mean_sides(zoomed), 1e-3)
    shift = np.linalg.norm(zoomed - refined, axis=2)
    x, y = zoomed[..., 0], zoomed[..., 1]
    border = np.minimum.reduce([x.min(1), (w - 1) - x.max(1), y.min(1), (h - 1) - y.max(1)])
    edges = np.linalg.norm(zoomed - np.roll(zoomed, -1, axis=1), axis=2)
    return np.stack([
        _logit(prob), _logit(stage), np.log(side), np.abs(sq_z[:, 0]), np.abs(sq_z[:, 1]),
        np.abs(sq_r[:, 0]), np.abs(sq_r[:, 1]), shift.mean(1) / side, shift.max(1) / side,
        np.clip(border, -20.0, 50.0), np.clip(border / side, -1.0, 3.0),
        np.log(edges.max(1) / np.maximum(edges.min(1), 1e-3)),
    ], axis=1)  # fmt: skip


def labels(
    zoomed: np.ndarray, truth: list[tuple[np.ndarray, np.ndarray, float]], min_gate_px: float
) -> np.ndarray:
    """(N,) per candidate: 1 if its corners match a counted gate under eval-detector's rule
    (mean corner distance at most max(4 px, a quarter of the gate's side)), -1 if they match
    only gates that are not counted (too small, cut by the frame, hidden corners: no label),
    0 if they match no labelled gate."""
    y = np.zeros(len(zoomed), int)
    for corners, vis, _ in truth:
        if not np.isfinite(corners).all():
            continue
        side = float(mean_sides(corners[None])[0])
        near = np.linalg.norm(zoomed - corners, axis=2).mean(1) <= max(4.0, 0.25 * side)
        counted = evaluable(corners, vis) and side >= min_gate_px
        y[near] = np.where(counted, 1, np.where(y[near] == 1, 1, -1))
    return y
