"""The fourth stage: a small MLP that scores each refined candidate from its numbers alone.

The refiner's probability times the first stage's score ranks candidates; the squareness check
then drops some. Neither looks at what the later stages measured: how far the zoom stage moved
the corners, how square the opening is in 3-D on either set of corners, how near the frame's edge
it lies. The rescorer reads those twelve numbers (:data:`FEATURES`) per candidate and returns the
probability that the candidate, as the zoom stage leaves it, matches a labelled gate under
eval-detector's rule (``gate_detect/metrics.py``). The detector then keeps candidates scoring at
least ``RescoreConfig.threshold``, best first, as before. Measured on val: the same precision with
more recall and PCK@5px (docs/history/detector.md).

It is trained on a detector's candidates on images none of its networks saw
(``icarus-vision train-rescorer``), costs a few microseconds a frame and is stored as
``rescore.safetensors`` plus a ``rescore`` section in ``detector.json`` (tensors only).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np
import torch
from numba import njit
from torch import nn

from icarus_vision.gate_detect.cnn.rectify import squareness
from icarus_vision.gate_detect.cnn.refine import NOMINAL_HFOV_DEG
from icarus_vision.gate_detect.metrics import match_tolerance, mean_side

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
            self._scale = (np.array(self.cfg.mean), np.array(self.cfg.std))
        h = _standardise(np.ascontiguousarray(x, np.float64), *self._scale)
        last = len(self._numpy) - 1
        for i, (w, b) in enumerate(self._numpy):
            h = _dense(h, w, b, i < last)
        return 1.0 / (1.0 + np.exp(-h[:, 0]))

    def load_state_dict(self, *args, **kwargs):  # the numpy copy follows new weights
        self._numpy = None
        return super().load_state_dict(*args, **kwargs)


@njit(cache=True)
def _standardise(x, mean, std):  # pragma: no cover (compiled)
    return (x - mean) / std


@njit(cache=True)
def _dense(h, w, b, relu):  # pragma: no cover (compiled)
    """One layer of the MLP: h @ w + b, then ReLU if ``relu``."""
    out = h @ w + b if len(h) else np.zeros((0, w.shape[1]))
    return np.maximum(out, 0.0) if relu else out


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
    zoomed = np.ascontiguousarray(zoomed, np.float64)
    refined = np.ascontiguousarray(refined, np.float64)
    sq_z = squareness(zoomed, image_size, NOMINAL_HFOV_DEG)
    sq_r = squareness(refined, image_size, NOMINAL_HFOV_DEG)
    return _features(np.asarray(prob, np.float64), np.asarray(stage, np.float64), refined,
                     zoomed, sq_z, sq_r, float(image_size[0]), float(image_size[1]))  # fmt: skip


@njit(cache=True)
def _features(prob, stage, refined, zoomed, sq_z, sq_r, w, h):  # pragma: no cover (compiled)
    """:func:`features` past the squareness, compiled: a frame's few candidates made one numpy
    call per step cost more than the arithmetic."""
    n = len(prob)
    out = np.empty((n, 12))
    for i in range(n):
        side, shift_sum, shift_max = 0.0, 0.0, 0.0
        e_max, e_min = 0.0, np.inf
        x_min, x_max, y_min, y_max = np.inf, -np.inf, np.inf, -np.inf
        for k in range(4):
            j = (k + 1) % 4
            e = math.hypot(zoomed[i, j, 0] - zoomed[i, k, 0], zoomed[i, j, 1] - zoomed[i, k, 1])
            side += e / 4.0
            e_max, e_min = max(e_max, e), min(e_min, e)
            d = math.hypot(zoomed[i, k, 0] - refined[i, k, 0], zoomed[i, k, 1] - refined[i, k, 1])
            shift_sum += d
            shift_max = max(shift_max, d)
            x_min, x_max = min(x_min, zoomed[i, k, 0]), max(x_max, zoomed[i, k, 0])
            y_min, y_max = min(y_min, zoomed[i, k, 1]), max(y_max, zoomed[i, k, 1])
        side = max(side, 1e-3)
        border = min(x_min, (w - 1) - x_max, y_min, (h - 1) - y_max)
        p = min(max(prob[i], PROB_EPS), 1.0 - PROB_EPS)
        s = min(max(stage[i], PROB_EPS), 1.0 - PROB_EPS)
        out[i, 0] = math.log(p / (1.0 - p))
        out[i, 1] = math.log(s / (1.0 - s))
        out[i, 2] = math.log(side)
        out[i, 3] = abs(sq_z[i, 0])
        out[i, 4] = abs(sq_z[i, 1])
        out[i, 5] = abs(sq_r[i, 0])
        out[i, 6] = abs(sq_r[i, 1])
        out[i, 7] = shift_sum / 4.0 / side
        out[i, 8] = shift_max / side
        out[i, 9] = min(max(border, -20.0), 50.0)
        out[i, 10] = min(max(border / side, -1.0), 3.0)
        out[i, 11] = math.log(e_max / max(e_min, 1e-3))
    return out


def labels(zoomed: np.ndarray, truth: list[tuple[np.ndarray, np.ndarray, float]]) -> np.ndarray:
    """(N,) per candidate: 1 if its corners match a labelled gate under eval-detector's rule (mean
    corner distance at most max(4 px, a quarter of the gate's side)), else 0. Every labelled gate
    counts, also those eval-detector does not (under 20 px, cut by the frame's edge, with hidden
    corners): they are gates, the estimator uses the small ones, and on val a rescorer taught so
    scored higher on the counted ones too (docs/history/detector.md)."""
    y = np.zeros(len(zoomed), int)
    for corners, _, _ in truth:
        if not np.isfinite(corners).all():
            continue
        near = np.linalg.norm(zoomed - corners, axis=2).mean(1) <= match_tolerance(
            mean_side(corners)
        )
        y[near] = 1
    return y
