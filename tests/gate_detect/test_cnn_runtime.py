"""Running the detector's networks on numpy arrays: PyTorch and ONNX Runtime alike."""

from __future__ import annotations

import numpy as np
import torch

from icarus_vision.gate_detect.cnn.refine import RefineConfig, RefineNet
from icarus_vision.gate_detect.cnn.runtime import OnnxRuntimeNet, run_network

CFG = RefineConfig(patch=40, margin=8)


def test_networks_run_on_numpy_alike_in_pytorch_and_onnx_runtime():
    torch.manual_seed(0)
    net = RefineNet(CFG).eval()
    x = np.random.default_rng(0).random((3, 3, 40, 40), dtype=np.float32)
    g = np.random.default_rng(1).random((3, CFG.num_geom), dtype=np.float32)
    ort_net = OnnxRuntimeNet(net, (torch.from_numpy(x), torch.from_numpy(g)), threads=1)
    a = run_network(net, x, g)
    b = run_network(ort_net, x, g)
    assert a.dtype == b.dtype == np.float32 and a.shape == b.shape == (3, 9)
    np.testing.assert_allclose(a, b, atol=1e-4)
    np.testing.assert_array_equal(ort_net(torch.from_numpy(x), torch.from_numpy(g)).numpy(), b)
