"""train-detector's moving average of the weights (``ema_decay``)."""

from __future__ import annotations

import pytest
import torch
from safetensors.torch import load_file
from typer.testing import CliRunner

from icarus_vision.cli import app
from icarus_vision.gate_detect.cnn.train import STATE, TrainConfig, train_detector
from tests.gate_detect.conftest import TINY_MODEL


def test_best_holds_the_moving_average_not_the_trained_weights(tiny_dataset, tmp_path):
    cfg = TrainConfig(batch_size=4, bf16=False, tune_decode=False, ema_decay=0.9)
    train_detector(tiny_dataset, tmp_path / "r", epochs=1, config=cfg, model_config=TINY_MODEL,
                   progress=False)  # fmt: skip
    best = load_file(tmp_path / "r" / "best" / "model.safetensors")
    trained = load_file(tmp_path / "r" / "last" / "model.safetensors")
    ema = torch.load(tmp_path / "r" / "last" / STATE, weights_only=True)["ema"]
    assert int(ema["n_averaged"]) > 1  # updated every step
    assert all(torch.equal(best[k], ema[f"module.{k}"]) for k in best)
    assert not all(torch.equal(best[k], trained[k]) for k in best)


@pytest.mark.parametrize("decay", ["1.0", "-0.1"])
def test_a_decay_outside_0_1_is_a_one_line_error(tiny_dataset, tmp_path, decay):
    r = CliRunner().invoke(app, ["train-detector", "--data", str(tiny_dataset), "--out",
                                 str(tmp_path / "o"), "--ema-decay", decay])  # fmt: skip
    lines = [s for s in r.output.strip().splitlines() if s.strip()]
    assert r.exit_code == 1 and len(lines) == 1 and "ema_decay" in lines[0], r.output
