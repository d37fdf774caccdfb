"""Validation of the corner network, and the choice of its decoding thresholds on the val split.

The network runs once over the split; decoding (cheap) is then repeated for each candidate
:class:`DecodeConfig`. Of those within ``SCORE_TIE`` of the best validation score, the one that
reports the fewest detections is kept: thresholds that score the same on val then lean towards
precision, and decoding fewer peaks is faster.
"""

from __future__ import annotations

import itertools
from dataclasses import replace

import numpy as np
import torch

from icarus_vision.gate_detect.cnn.data import Split
from icarus_vision.gate_detect.cnn.decode import DecodeConfig, decode
from icarus_vision.gate_detect.cnn.model import CornerNet
from icarus_vision.gate_detect.metrics import evaluate_image, summarize

CENTRE_THRESHOLDS = (0.2, 0.3, 0.4, 0.5)
CORNER_THRESHOLDS = (0.1, 0.2, 0.3)
SNAP_RADII = (0.3, 0.4)
MIN_SNAPPED = (0, 3)
SURE_CENTRES = (1.0, 0.6)
NESTED_RESIDUALS = (0.05, 0.08)
SCORE_TIE = 0.001
"""Validation scores this close to the best count as equally good."""


def score(metrics: dict) -> float:
    """Validation score: mean of precision, recall, PCK@5px and PCK@2px (missing counts 0)."""
    vals = [metrics["precision"], metrics["recall"], metrics["pck"]["5px"], metrics["pck"]["2px"]]
    return float(np.mean([v or 0.0 for v in vals]))


def network_outputs(model: CornerNet, split: Split, batch: int = 32) -> torch.Tensor:
    """(N, 15, h, w) raw outputs of the network (eval mode) on a split loaded with images."""
    was_training = model.training
    model.eval()
    outs = []
    with torch.inference_mode():
        for i in range(0, len(split.files), batch):
            x = split.images[i : i + batch].transpose(0, 3, 1, 2).astype(np.float32) / 255.0
            outs.append(model(torch.from_numpy(x)))
    model.train(was_training)
    return torch.cat(outs)


def metrics_of(outputs: torch.Tensor, split: Split, cfg: DecodeConfig, min_gate_px: float) -> dict:
    """:func:`~icarus_vision.gate_detect.metrics.summarize` of decoded outputs against the split."""
    w, h = split.image_size
    gts, preds = [], []
    for o, gates in zip(outputs, split.gates, strict=True):
        found = decode(o, cfg, (w / o.shape[-1], h / o.shape[-2]))
        truth = [(g.corners, g.visibility, g.distance) for g in gates]
        g_rec, p_rec = evaluate_image([(c, s) for c, _, s in found], truth, min_gate_px)
        gts += g_rec
        preds += p_rec
    return {**summarize(gts, preds, min_gate_px), "detections": len(preds)}


def validate(model: CornerNet, split: Split, cfg: DecodeConfig, min_gate_px: float) -> dict:
    """Validation metrics of the network with decoding ``cfg``."""
    return metrics_of(network_outputs(model, split), split, cfg, min_gate_px)


def tune_decode(
    model: CornerNet, split: Split, base: DecodeConfig, min_gate_px: float
) -> tuple[DecodeConfig, dict]:
    """The decoding thresholds (grid above) with the best :func:`score` on ``split`` (ties:
    module docstring).

    Returns:
        (best config, its metrics).
    """
    outputs = network_outputs(model, split)
    tried = []
    grid = itertools.product(
        CENTRE_THRESHOLDS, CORNER_THRESHOLDS, SNAP_RADII, MIN_SNAPPED, SURE_CENTRES,
        NESTED_RESIDUALS,
    )  # fmt: skip
    for c, k, r, n, sure, fit in grid:
        cfg = replace(
            base, centre_threshold=c, corner_threshold=k, snap_radius=r, min_snapped=n,
            sure_centre=sure, nested_residual=fit,
        )  # fmt: skip
        tried.append((cfg, metrics_of(outputs, split, cfg, min_gate_px)))
    return choose(tried)


def choose(tried: list[tuple[DecodeConfig, dict]]) -> tuple[DecodeConfig, dict]:
    """Of (config, metrics) pairs, the one with the fewest ``detections`` among those whose
    :func:`score` is within ``SCORE_TIE`` of the best (then the higher score, then the first)."""
    top = max(score(m) for _, m in tried)
    near = [(m["detections"], -score(m), i) for i, (_, m) in enumerate(tried)
            if score(m) >= top - SCORE_TIE]  # fmt: skip
    return tried[min(near)[2]]
