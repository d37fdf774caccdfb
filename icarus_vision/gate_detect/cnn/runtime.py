"""Running the detector's networks: ONNX Runtime, or PyTorch, numpy arrays in and out.

Between the networks, the detector works in numpy on a frame's few candidates. Calling ONNX
Runtime directly on numpy arrays spares each call a dozen small PyTorch conversions: a frame
calls the networks two or three times, and each conversion right after a network is slow (the
network's weights have just evicted the caches).
"""

from __future__ import annotations

import numpy as np
import torch
from torch import nn

DISABLED = ["WeightBiasQuantization"]
"""ONNX Runtime graph optimizations not applied. ``WeightBiasQuantization`` quantizes the float32
weights of a convolution that reads a dequantized input and feeds a quantized output, per
tensor and to the full 8 bits: it made int8 the layers an int8 copy keeps in float32
(``quantize.FLOAT_LAYERS``: the zoom stage's first layer, the corner network's ``lat1``), and
on CPUs without VNNI its 8-bit weights can overflow the AVX2 kernels' 16-bit sums (the zoom
stage's outputs were off by up to 0.017 against the same graph computed unfused; 0.0005
without it)."""


class OnnxRuntimeNet:
    """A network exported to ONNX and run by ONNX Runtime on the CPU: :meth:`run` takes and
    returns numpy arrays; called, it works like the module it came from (torch tensors in, one
    float32 torch tensor out). Its ``onnx`` is the ONNX model it runs (bytes).

    Args:
        module: the network (exported once, here, in eval mode).
        example: example inputs; their first (batch) dimension may differ between calls.
        threads: ONNX Runtime's intra-op threads (None: its default, every core).
    """

    def __init__(self, module: nn.Module, example: tuple[torch.Tensor, ...], threads: int | None):
        from icarus_vision.gate_detect.cnn.checkpoint import onnx_bytes

        names = [f"input{i}" for i in range(len(example))]
        self.onnx = onnx_bytes(
            module, example, input_names=names, output_names=["output"],
            dynamic_axes={n: {0: "n"} for n in [*names, "output"]},
        )  # fmt: skip
        self._start(self.onnx, threads)

    @classmethod
    def from_onnx(
        cls, model: bytes, threads: int | None, source: str = "ONNX model"
    ) -> OnnxRuntimeNet:
        """A network from an ONNX model's bytes (an int8 copy: ``quantize.py``); one that ONNX
        Runtime cannot load is a ValueError naming ``source``."""
        net = cls.__new__(cls)
        net.onnx = model
        try:
            net._start(model, threads)
        except Exception as e:  # noqa: BLE001 - ONNX Runtime raises its own exception types
            msg = str(e).splitlines()[0] if str(e) else type(e).__name__
            raise ValueError(f"{source}: not a model ONNX Runtime can run ({msg})") from None
        return net

    def _start(self, model: bytes, threads: int | None) -> None:
        import onnxruntime as ort

        opts = ort.SessionOptions()
        if threads is not None:
            opts.intra_op_num_threads = threads
            opts.inter_op_num_threads = 1
        self._session = ort.InferenceSession(
            model, opts, providers=["CPUExecutionProvider"], disabled_optimizers=DISABLED
        )
        self._names = [i.name for i in self._session.get_inputs()]

    def run(self, *inputs: np.ndarray) -> np.ndarray:
        """float32 C-contiguous arrays in (no copy), the float32 output out."""
        return self._session.run(None, dict(zip(self._names, inputs, strict=True)))[0]

    def __call__(self, *inputs: torch.Tensor) -> torch.Tensor:
        return torch.from_numpy(
            self.run(*(np.ascontiguousarray(t.detach().float().numpy()) for t in inputs))
        )


def run_network(
    net: nn.Module | OnnxRuntimeNet, *inputs: np.ndarray, dtype: torch.dtype = torch.float32
) -> np.ndarray:
    """The float32 output of ``net`` on float32 C-contiguous ``inputs``: a network with a
    numpy ``run`` method (an :class:`OnnxRuntimeNet`) runs on them as they are; a PyTorch one
    (a module or a traced one) reads them cast to ``dtype``, in inference mode."""
    run = getattr(net, "run", None)
    if run is not None:
        return run(*inputs)
    with torch.inference_mode():
        return net(*(torch.from_numpy(x).to(dtype) for x in inputs)).float().numpy()
