"""Int8 copies of the detector's networks: ONNX Runtime static quantization, calibrated on frames.

Each network (the corner network, the refiner, the zoom stage) is exported to ONNX in float32
(batch norm folded) and quantized by ``onnxruntime.quantization.quantize_static``: weights to
7-bit integers per output channel, activations to uint8 with ranges seen on calibration inputs
(min-max), in the QDQ format that ONNX Runtime fuses into int8 kernels. The 7 bits are for CPUs
without 8-bit dot products (VNNI, AMX): there ONNX Runtime's AVX2 kernels add pairs of
uint8 x int8 products in 16 bits, which 8-bit weights can overflow (255 x 127 x 2 > 32,767; its
quantization guide advises ``reduce_range``), and did in the refiner (outputs off by up to 1.7
against the same graph computed unfused; 0.04 with 7 bits). With 7 bits no sum saturates, so
every x86 CPU with AVX2 computes the same sums as one with VNNI. The calibration inputs are what
each network reads while the float32 detector runs on a dataset's frames, so the refiner and
the zoom stage are calibrated on real candidates and corners.

Layers where 8 bits cost accuracy stay float32 (:data:`FLOAT_LAYERS`): each network's first
convolution (it reads the raw image) and its output layer (the corner offsets, read to a tenth
of a pixel); in the corner network also the full-resolution layers of the decoder path (its
centre scores decide which candidates the refiner sees). Chosen on a val split: README,
Detection.
"""

from __future__ import annotations

import logging
import tempfile
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path

import numpy as np
from torch import nn

from icarus_vision.fileio import atomic_write_bytes
from icarus_vision.gate_detect.cnn import CnnDetector
from icarus_vision.gate_detect.cnn.checkpoint import (
    CONFIG,
    FLOAT_WEIGHTS,
    load_checkpoint,
    load_refiner,
    load_zoom,
    resolve,
    save_int8,
)
from icarus_vision.gate_detect.cnn.data import load_split, read_rgb
from icarus_vision.gate_detect.evaluate import one_thread

FLOAT_LAYERS = {
    "model": ("stem", "enc1.0", "lat1", "up1", "out"),
    "refiner": ("features.0", "out"),
    "zoom": ("features.0", "head.3"),
}
"""Modules of each network left in float32 (their names in the PyTorch module; a corner network
without a stem has no ``stem``: :func:`float_layers`)."""


def float_layers(net: nn.Module, name: str) -> list[str]:
    """The modules of :data:`FLOAT_LAYERS` ``[name]`` that are layers of ``net`` (have weights)."""
    modules = dict(net.named_modules())
    return [m for m in FLOAT_LAYERS[name]
            if m in modules and next(modules[m].parameters(), None) is not None]  # fmt: skip


WEIGHT_BITS = 7
"""Bits of the quantized weights (``reduce_range``: module docstring); recorded in the
checkpoint's ``int8`` section, where ``CnnDetector`` reads where the copies can run."""

METHOD = "MinMax"
"""How activation ranges are calibrated (``onnxruntime.quantization.CalibrationMethod``)."""

EXTRA_FILES = ("error_model.json",)
"""Files copied with a checkpoint besides its JSON and weights."""


class _Recorder:
    """A network with a numpy ``run`` that keeps every input it was given."""

    def __init__(self, net) -> None:
        self.net, self.inputs = net, []

    def run(self, *inputs: np.ndarray) -> np.ndarray:
        self.inputs.append([x.copy() for x in inputs])
        return self.net.run(*inputs)


def calibration_inputs(
    detector: CnnDetector,
    images: Iterable[np.ndarray],
    progress: Callable[[int], None] | None = None,
) -> dict[str, list[list[np.ndarray]]]:
    """Every input each network of an ONNX Runtime float32 ``detector`` reads while it detects
    in ``images``, by network name (``model``, ``refiner``, ``zoom``: those it has)."""
    if detector.backend != "onnxruntime":
        raise ValueError(
            f"calibration runs the float32 onnxruntime backend, not {detector.backend}"
        )
    recorders = {"model": _Recorder(detector.model)}
    detector._nets["onnxruntime"] = recorders["model"]  # what its `model` returns from now on
    for name in ("refiner", "zoom"):
        if getattr(detector, name) is not None:
            recorders[name] = _Recorder(getattr(detector, name))
            setattr(detector, name, recorders[name])
    with one_thread():
        for i, image in enumerate(images):
            detector.detect(image)
            if progress is not None:
                progress(i + 1)
    return {name: r.inputs for name, r in recorders.items()}


def layer_nodes(model: bytes, modules: Sequence[str]) -> list[str]:
    """The names of the ONNX ``model``'s nodes that belong to PyTorch ``modules`` (the exporter
    names a node by its module path: module ``enc1.0`` -> ``/enc1/enc1.0/...``)."""
    import onnx

    graph = onnx.load_from_string(model).graph
    found = []
    for module in modules:
        parts = module.split(".")
        prefix = "/" + "/".join(".".join(parts[: i + 1]) for i in range(len(parts))) + "/"
        nodes = [n.name for n in graph.node if n.name.startswith(prefix)]
        if not nodes:
            raise ValueError(f"no ONNX node belongs to module {module!r} (prefix {prefix})")
        found += nodes
    return found


def quantize_network(
    model: bytes, batches: list[list[np.ndarray]], float_layers: Sequence[str]
) -> bytes:
    """The float32 ONNX ``model`` quantized to int8 (QDQ; 7-bit weights per channel), activation
    ranges from ``batches`` of its inputs, the nodes of ``float_layers`` left in float32."""
    import onnx
    from onnxruntime.quantization import (
        CalibrationDataReader,
        CalibrationMethod,
        QuantFormat,
        QuantType,
        quantize_static,
    )

    names = [i.name for i in onnx.load_from_string(model).graph.input]

    class Reader(CalibrationDataReader):
        def __init__(self) -> None:
            self._batches = iter(batches)

        def get_next(self) -> dict | None:
            batch = next(self._batches, None)
            return None if batch is None else dict(zip(names, batch, strict=True))

    root = logging.getLogger()
    level = root.level
    # Its advice to pre-process the model first (shape inference, graph optimisation) is logged
    # as a warning on every call; the exported networks quantize without it.
    root.setLevel(logging.ERROR)
    try:
        with tempfile.TemporaryDirectory() as tmp:
            src, dst = Path(tmp) / "float.onnx", Path(tmp) / "int8.onnx"
            src.write_bytes(model)
            quantize_static(
                src, dst, Reader(), quant_format=QuantFormat.QDQ, per_channel=True,
                activation_type=QuantType.QUInt8, weight_type=QuantType.QInt8,
                reduce_range=WEIGHT_BITS < 8, calibrate_method=getattr(CalibrationMethod, METHOD),
                nodes_to_exclude=layer_nodes(model, float_layers),
                extra_options={"CalibMaxIntermediateOutputs": 64},  # bounds calibration's memory
            )  # fmt: skip
            return dst.read_bytes()
    finally:
        root.setLevel(level)


def calibration_files(data: Sequence[str | Path], split: str, images: int, seed: int) -> list[Path]:
    """``images`` frames drawn at random (``seed``) from the ``split`` splits of ``data``, in
    dataset order (all of them if there are fewer)."""
    if images < 1:
        raise ValueError(f"images must be >= 1, got {images}")
    files = [f for d in data for f in load_split(d, split, None, None).files]
    if not files:
        raise ValueError(f"no {split} images in {', '.join(map(str, data))}")
    rng = np.random.default_rng(seed)
    picked = np.sort(rng.choice(len(files), min(images, len(files)), replace=False))
    return [files[i] for i in picked]


def quantize_detector(
    detector: str | Path | None,
    data: Sequence[str | Path],
    out: str | Path,
    images: int = 400,
    split: str = "val",
    seed: int = 0,
    progress: Callable[[int, int], None] | None = None,
) -> dict:
    """Write a copy of the checkpoint ``detector`` (None: the shipped one) to ``out`` (or add to
    it in place, if ``out`` is that folder; a folder holding another checkpoint is refused, not
    overwritten) with int8 copies of its networks, calibrated on
    ``images`` frames of ``data``'s ``split`` (drawn with ``seed``); returns the JSON's new
    ``int8`` section (``networks``: their names). ``progress`` is called with (frames done, frames)."""
    from icarus_vision.gate_detect.cnn.checkpoint import SHIPPED

    source = resolve(SHIPPED if detector is None else detector)
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise ValueError(f"{out}: not a folder (--out is the checkpoint folder to write)")
    if (out / CONFIG).is_file() and out.resolve() != source.resolve():
        raise ValueError(
            f"{out} holds another checkpoint, which a copy of {source} would replace: to add "
            f"int8 copies to it, pass --detector cnn:{out}; else choose an empty --out"
        )
    files = calibration_files(data, split, images, seed)
    model, decode_cfg, meta = load_checkpoint(source)
    refiner, zoom = load_refiner(source, meta), load_zoom(source, meta)
    torch_nets = {"model": model, "refiner": refiner, "zoom": zoom}
    keep = {name: float_layers(net, name) for name, net in torch_nets.items() if net is not None}
    # built from these networks, not CnnDetector.load: that refuses stale int8 copies, which
    # are what this replaces
    float_det = CnnDetector(model, decode_cfg, refiner=refiner, zoom=zoom, backend="onnxruntime")
    nets = {"model": float_det.model, "refiner": float_det.refiner, "zoom": float_det.zoom}
    onnx_models = {name: net.onnx for name, net in nets.items() if net is not None}
    step = None if progress is None else (lambda i: progress(i, len(files)))
    inputs = calibration_inputs(float_det, (read_rgb(f) for f in files), step)
    idle = [name for name in onnx_models if not inputs[name]]
    if idle:
        raise ValueError(
            f"the {' and '.join(idle)} read nothing on {len(files)} calibration frames: use "
            "more frames (--images), or frames with gates"
        )
    int8 = {name: quantize_network(m, inputs[name], keep[name])
            for name, m in onnx_models.items()}  # fmt: skip
    out.mkdir(parents=True, exist_ok=True)
    if out.resolve() != source.resolve():
        for name in (CONFIG, *FLOAT_WEIGHTS.values(), *EXTRA_FILES):
            if (source / name).is_file():
                atomic_write_bytes(out / name, (source / name).read_bytes())
    import onnxruntime

    record = {
        "method": f"onnxruntime static quantization, QDQ, {WEIGHT_BITS}-bit weights per "
        f"channel (reduce_range), uint8 activations ({METHOD} calibration)",
        "weight_bits": WEIGHT_BITS,
        "onnxruntime": onnxruntime.__version__,
        "calibration": {
            "data": [str(d) for d in data],
            "split": split,
            "images": len(files),
            "seed": seed,
        },
        "float_layers": keep,
    }
    save_int8(out, int8, record)
    return {**record, "networks": sorted(int8)}
