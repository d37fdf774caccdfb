"""The CNN detector's frozen (TorchScript) network gives exactly the eager network's output."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from torch import nn

from icarus_vision.gate_detect.cnn import CnnDetector, frozen_trace
from icarus_vision.gate_detect.cnn.decode import DecodeConfig
from icarus_vision.gate_detect.cnn.model import CornerNet
from tests.gate_detect.conftest import TINY_MODEL


@pytest.mark.parametrize("bf16", [False, True])
def test_frozen_detector_detects_as_the_eager_one(bf16):
    torch.manual_seed(0)
    model = CornerNet(TINY_MODEL)
    eager, frozen = (
        CnnDetector(model, DecodeConfig(centre_threshold=0.0), bf16=bf16, frozen=f, backend="torch")
        for f in (False, True)
    )
    assert not isinstance(frozen.model, CornerNet) and isinstance(eager.model, CornerNet)
    eager.frozen = True  # the setting can change after construction
    assert not isinstance(eager.model, CornerNet)
    eager.frozen = False
    w, h = TINY_MODEL.input_size
    images = np.random.default_rng(0).integers(0, 256, (3, h, w, 3), dtype=np.uint8)
    a, b = eager.detect_batch(list(images)), frozen.detect_batch(list(images))
    assert sum(map(len, a)) > 0
    for da, db in zip(a, b, strict=True):
        assert len(da) == len(db)
        for ga, gb in zip(da, db, strict=True):
            np.testing.assert_array_equal(ga.corners, gb.corners)
            assert ga.score == gb.score


def test_a_network_that_cannot_be_traced_runs_as_it_is():
    class DictOut(nn.Module):  # a dict output fails strict tracing
        def forward(self, x):
            return {"maps": x}

    net = DictOut()
    assert frozen_trace(net, torch.zeros(1, 3, 4, 4)) is net


def test_onnxruntime_backend_detects_as_pytorch():
    torch.manual_seed(0)
    model = CornerNet(TINY_MODEL)
    dets = [CnnDetector(model, DecodeConfig(centre_threshold=0.0), bf16=False, backend=b)
            for b in ("torch", "onnxruntime")]  # fmt: skip
    assert dets[1].backend == "onnxruntime" and not isinstance(dets[1].model, nn.Module)
    w, h = TINY_MODEL.input_size
    images = list(np.random.default_rng(1).integers(0, 256, (3, h, w, 3), dtype=np.uint8))
    a, b = (d.detect_batch(images) for d in dets)  # a batch of three: the batch size may vary
    assert sum(map(len, a)) > 0
    for da, db in zip(a, b, strict=True):
        assert len(da) == len(db)
        for ga, gb in zip(da, db, strict=True):
            np.testing.assert_allclose(ga.corners, gb.corners, atol=1e-3)


def test_backend_choice_and_bad_backends():
    model = CornerNet(TINY_MODEL)
    assert CnnDetector(model, bf16=True).backend == "torch"  # auto: bfloat16 runs on PyTorch
    assert CnnDetector(model, bf16=False).backend == "onnxruntime"
    with pytest.raises(ValueError, match="backend must be one of"):
        CnnDetector(model, backend="tensorrt")
    with pytest.raises(ValueError, match="bf16"):
        CnnDetector(model, bf16=True, backend="onnxruntime")
