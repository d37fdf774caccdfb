"""Int8 copies of the detector's networks: quantize-detector, loading them, choosing the backend."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest
import torch
from safetensors.torch import load_file, save_file
from torch import nn
from typer.testing import CliRunner

import icarus_vision.gate_detect.cnn as cnn
from icarus_vision.cli import app
from icarus_vision.gate_detect.cnn import CnnDetector, OnnxRuntimeNet
from icarus_vision.gate_detect.cnn.checkpoint import (
    INT8,
    load_checkpoint,
    load_refiner,
    onnx_bytes,
    save_checkpoint,
)
from icarus_vision.gate_detect.cnn.data import load_split, read_rgb
from icarus_vision.gate_detect.cnn.decode import DecodeConfig
from icarus_vision.gate_detect.cnn.model import CornerNet
from icarus_vision.gate_detect.cnn.quantize import calibration_inputs, layer_nodes, quantize_network
from icarus_vision.gate_detect.cnn.refine import RefineConfig, RefineNet
from icarus_vision.gate_detect.cnn.zoom import ZoomConfig, ZoomNet

from .conftest import TINY_MODEL

runner = CliRunner()


def _checkpoint(folder):
    """Untrained tiny networks whose every stage has work on the tiny dataset's frames."""
    torch.manual_seed(1)
    corner = CornerNet(TINY_MODEL).eval()
    refiner = RefineNet(RefineConfig(patch=40, margin=8)).eval()
    zoom = ZoomNet(ZoomConfig(patch=24, widths=(4, 8, 8, 8), hidden=16, min_side_px=4.0)).eval()
    with torch.no_grad():  # centre peaks regressing a square; a refiner that believes them all
        corner.out.bias[0] = 0.0
        corner.out.bias[7:15] = torch.tensor([-0.5, -0.5, 0.5, -0.5, 0.5, 0.5, -0.5, 0.5])
        refiner.out.bias[0] = 5.0
    return save_checkpoint(folder, corner, DecodeConfig(centre_threshold=0.0), {}, refiner,
                           {}, zoom, {})  # fmt: skip


def _quantize(src, data, out, *extra):
    args = ["quantize-detector", "--detector", f"cnn:{src}", "--data", str(data), "--out",
            str(out), *extra]  # fmt: skip
    return runner.invoke(app, args)


@pytest.fixture(scope="module")
def quantized(tiny_dataset, tmp_path_factory):
    root = tmp_path_factory.mktemp("quantized")
    src = _checkpoint(root / "float")
    res = _quantize(src, tiny_dataset, root / "int8", "--images", "3", "--seed", "2")
    assert res.exit_code == 0, res.output
    return src, root / "int8"


def test_quantize_detector_writes_a_checkpoint_with_int8_networks(quantized, tiny_dataset):
    src, out = quantized
    assert not any((src / f).exists() for f in INT8.values())  # the source is left as it was
    meta = json.loads((out / "detector.json").read_text())["int8"]
    assert sorted(meta["networks"]) == ["model", "refiner", "zoom"]
    assert meta["calibration"] == {"data": [str(tiny_dataset)], "split": "val", "images": 3,
                                   "seed": 2}  # fmt: skip
    assert meta["weight_bits"] == 7
    # the first and output layers stay float32 (this corner network has no stem)
    assert meta["float_layers"] == {"model": ["enc1.0", "lat1", "up1", "out"],
                                    "refiner": ["features.0", "out"], "zoom": ["features.0", "head.3"]}  # fmt: skip
    for name, file in INT8.items():
        assert (out / file).is_file() and meta["networks"][name]["file"] == file
    det = CnnDetector.load(out, backend="int8")
    assert all(isinstance(n, OnnxRuntimeNet) for n in (det.model, det.refiner, det.zoom))


def test_int8_networks_read_as_the_float_ones(quantized, tiny_dataset):
    _, out = quantized
    images = [read_rgb(f) for f in load_split(tiny_dataset, "val", None, None).files]
    inputs = calibration_inputs(CnnDetector.load(out, backend="onnxruntime"), images)
    float_det, int8_det = (CnnDetector.load(out, backend=b) for b in ("onnxruntime", "int8"))
    for name in ("model", "refiner", "zoom"):
        a, b = getattr(float_det, name), getattr(int8_det, name)
        for batch in inputs[name]:
            x, y = a.run(*batch), b.run(*batch)
            assert not np.array_equal(x, y) and x.shape == y.shape  # it is another network...
            if cnn.int8_runs_exactly(7):  # (else ONNX Runtime's int8 sums can saturate)
                # ... within a few per cent of the outputs' range (7-bit steps, several layers)
                assert np.abs(x - y).max() <= 0.05 * (np.ptp(x) + 1e-6), name


@pytest.mark.skipif(not cnn.int8_runs_exactly(7), reason="a CPU without AVX2 or VNNI")
def test_int8_kernels_sum_without_saturating():
    """ONNX Runtime's fused int8 kernels compute what the same quantized graph computes unfused
    (dequantized to float32, node by node), even where inputs and weights are all at the top of
    their ranges: with 8-bit weights, pairs of products overflow AVX2's 16-bit sums here."""
    import onnxruntime as ort

    net = nn.Sequential(nn.Conv2d(16, 8, 1), nn.ReLU(), nn.Conv2d(8, 4, 1)).eval()
    with torch.no_grad():
        net[0].weight.fill_(1.0)
        net[0].bias.zero_()
    x = np.ones((2, 16, 8, 8), np.float32)
    x[1] *= np.random.default_rng(0).uniform(0.9, 1.0, (16, 8, 8)).astype(np.float32)
    model = onnx_bytes(net, (torch.from_numpy(x),), input_names=["input0"],
                       output_names=["output"], dynamic_axes={"input0": {0: "n"}})  # fmt: skip
    int8 = quantize_network(model, [[x]], [])
    outs = []
    for level in (ort.GraphOptimizationLevel.ORT_ENABLE_ALL,
                  ort.GraphOptimizationLevel.ORT_DISABLE_ALL):  # fmt: skip
        opts = ort.SessionOptions()
        opts.graph_optimization_level = level
        session = ort.InferenceSession(int8, opts, providers=["CPUExecutionProvider"])
        outs.append(session.run(None, {"input0": x})[0])
    np.testing.assert_allclose(outs[0], outs[1], atol=1e-3 * np.ptp(outs[1]))


class _Normalised(nn.Module):
    """A convolution reading its input normalised in the graph (so, in an int8 copy, a
    dequantized input), as the zoom stage's first layer does, then int8-able layers."""

    def __init__(self) -> None:
        super().__init__()
        self.first = nn.Sequential(nn.Conv2d(3, 4, 3, padding=1), nn.ReLU())
        self.rest = nn.Sequential(nn.Conv2d(4, 4, 1), nn.ReLU(), nn.Conv2d(4, 4, 1))

    def forward(self, x):
        return self.rest(self.first((x - 0.5) * 2.0))


def test_a_layer_kept_float32_stays_float32_in_onnx_runtime():
    """A layer an int8 copy keeps in float32 is computed in float32 by the detector's runtime,
    even where it reads a dequantized input and feeds a quantized output (where ONNX Runtime's
    own optimizations would quantize its weights). Here one huge weight reads a channel that is
    always 0: harmless in float32, but quantized to 8 bits with it, every other weight becomes 0."""
    import onnxruntime as ort

    torch.manual_seed(0)
    net = _Normalised().eval()
    with torch.no_grad():
        net.first[0].weight[:, 2] = 1000.0
    x = np.random.default_rng(0).uniform(0, 1, (2, 3, 8, 8)).astype(np.float32)
    x[:, 2] = 0.5  # normalised to 0
    model = onnx_bytes(net, (torch.from_numpy(x),), input_names=["input0"],
                       output_names=["output"], dynamic_axes={"input0": {0: "n"}})  # fmt: skip
    int8 = quantize_network(model, [[x]], ["first"])
    opts = ort.SessionOptions()
    opts.graph_optimization_level = ort.GraphOptimizationLevel.ORT_DISABLE_ALL
    unfused = ort.InferenceSession(int8, opts, providers=["CPUExecutionProvider"])
    expected = unfused.run(None, {"input0": x})[0]
    assert np.ptp(expected) > 0.1
    got = OnnxRuntimeNet.from_onnx(int8, threads=1).run(x)
    np.testing.assert_allclose(got, expected, atol=0.02 * np.ptp(expected))


def test_same_seed_same_int8_networks_and_another_seed_other_frames(quantized, tiny_dataset,
                                                                    tmp_path):  # fmt: skip
    src, out = quantized
    assert (
        _quantize(src, tiny_dataset, tmp_path / "a", "--images", "3", "--seed", "2").exit_code == 0
    )
    for file in INT8.values():
        assert (tmp_path / "a" / file).read_bytes() == (out / file).read_bytes()
    assert (
        _quantize(src, tiny_dataset, tmp_path / "b", "--images", "3", "--seed", "9").exit_code == 0
    )
    assert (tmp_path / "b" / INT8["model"]).read_bytes() != (out / INT8["model"]).read_bytes()


def test_auto_runs_int8_only_where_the_cpu_sums_exactly(quantized, monkeypatch, tmp_path):
    _, out = quantized
    monkeypatch.setattr(cnn, "native_int8", lambda: True)
    monkeypatch.setattr(cnn, "has_avx2", lambda: False)
    assert CnnDetector.load(out).backend == "int8"
    assert CnnDetector.load(out, bf16=True).backend == "torch"
    monkeypatch.setattr(cnn, "native_int8", lambda: False)
    assert CnnDetector.load(out).backend == "onnxruntime"
    monkeypatch.setattr(cnn, "has_avx2", lambda: True)  # 7-bit weights: exact with AVX2
    assert CnnDetector.load(out).backend == "int8"
    # copies with 8-bit weights (made before quantize-detector recorded their bits) could
    # saturate there: float32
    eight = tmp_path / "eight"
    eight.mkdir()
    for f in out.iterdir():
        (eight / f.name).write_bytes(f.read_bytes())
    meta = json.loads((eight / "detector.json").read_text())
    del meta["int8"]["weight_bits"]
    (eight / "detector.json").write_text(json.dumps(meta))
    assert CnnDetector.load(eight).backend == "onnxruntime"
    monkeypatch.setattr(cnn, "native_int8", lambda: True)
    assert CnnDetector.load(eight).backend == "int8"
    monkeypatch.setattr(cnn, "native_int8", lambda: False)
    meta["int8"]["weight_bits"] = "7"
    (eight / "detector.json").write_text(json.dumps(meta))
    with pytest.raises(ValueError, match="weight_bits"):
        CnnDetector.load(eight)
    src, _ = quantized
    monkeypatch.setattr(cnn, "native_int8", lambda: True)  # no int8 copies: float32
    assert CnnDetector.load(src).backend == "onnxruntime"
    with pytest.raises(ValueError, match="quantize-detector"):
        CnnDetector.load(src, backend="int8")
    with pytest.raises(ValueError, match="bf16"):
        CnnDetector.load(out, backend="int8", bf16=True)


def test_eval_detector_reports_the_backend_it_ran(quantized, tiny_dataset, tmp_path, monkeypatch):
    _, out = quantized
    monkeypatch.setattr(cnn, "native_int8", lambda: True)
    res = runner.invoke(app, ["eval-detector", "--data", str(tiny_dataset), "--detector",
                              f"cnn:{out}", "--json", str(tmp_path / "r.json"), "--resamples", "0"])  # fmt: skip
    assert res.exit_code == 0, res.output
    assert json.loads((tmp_path / "r.json").read_text())["backend"] == "int8"
    assert "(one core, int8; " in res.output


def test_eval_detector_runs_the_backend_asked_for(quantized, tiny_dataset, tmp_path):
    _, out = quantized
    args = ["eval-detector", "--data", str(tiny_dataset), "--resamples", "0", "--limit", "2"]
    for backend in ("onnxruntime", "int8"):
        res = runner.invoke(app, [*args, "--detector", f"cnn:{out}", "--backend", backend,
                                  "--json", str(tmp_path / f"{backend}.json")])  # fmt: skip
        assert res.exit_code == 0, res.output
        assert json.loads((tmp_path / f"{backend}.json").read_text())["backend"] == backend
    res = runner.invoke(app, [*args, "--detector", "opencv", "--backend", "int8"])
    assert res.exit_code != 0 and "the opencv detector takes no setting backend" in res.output
    res = runner.invoke(app, [*args, "--detector", f"cnn:{out}", "--backend", "gpu"])
    assert res.exit_code != 0 and "backend must be one of" in res.output


def test_stale_or_corrupt_int8_networks_name_the_file(quantized, tiny_dataset, tmp_path):
    _, out = quantized
    folder = tmp_path / "ck"
    folder.mkdir()
    for f in out.iterdir():
        (folder / f.name).write_bytes(f.read_bytes())
    model, decode, _ = load_checkpoint(folder)

    state = {k: v + 1.0 if v.is_floating_point() else v for k, v in model.state_dict().items()}
    save_file(state, str(folder / "model.safetensors"))  # new weights, the old int8 copies
    with pytest.raises(ValueError, match=r"model\.int8\.onnx.*other weights"):
        CnnDetector.load(folder)
    # quantizing a checkpoint with stale copies again, in place, is what mends it
    refreshed = tmp_path / "refreshed"
    refreshed.mkdir()
    for f in out.iterdir():
        (refreshed / f.name).write_bytes(f.read_bytes())
    zoom = load_file(refreshed / "zoom.safetensors")
    save_file({k: v + 0.01 if v.is_floating_point() else v for k, v in zoom.items()},
              str(refreshed / "zoom.safetensors"))  # fmt: skip
    with pytest.raises(ValueError, match=r"zoom\.int8\.onnx.*other weights"):
        CnnDetector.load(refreshed)
    res = _quantize(refreshed, tiny_dataset, refreshed, "--images", "3", "--seed", "2")
    assert res.exit_code == 0, res.output
    assert CnnDetector.load(refreshed, backend="int8").backend == "int8"
    (folder / "model.safetensors").write_bytes((out / "model.safetensors").read_bytes())
    (folder / "zoom.int8.onnx").write_bytes(b"garbage")
    with pytest.raises(ValueError, match=r"zoom\.int8\.onnx.*not an ONNX model"):
        CnnDetector.load(folder)
    (folder / "zoom.int8.onnx").unlink()
    with pytest.raises(FileNotFoundError, match=r"zoom\.int8\.onnx"):
        CnnDetector.load(folder)
    # saving the checkpoint again drops its int8 copies, which no longer match
    save_checkpoint(folder, model, replace(decode, centre_threshold=0.5))
    assert not any((folder / f).exists() for f in INT8.values())
    assert "int8" not in json.loads((folder / "detector.json").read_text())


def test_bad_calibration_requests_give_one_line_errors(quantized, tiny_dataset, tmp_path):
    src, _ = quantized
    res = _quantize(src, tiny_dataset, tmp_path / "x", "--detector", "opencv")
    assert res.exit_code == 1 and "cnn or cnn:PATH" in res.output
    res = _quantize(src, tmp_path / "nowhere", tmp_path / "x")
    assert res.exit_code == 1 and "nowhere" in res.output
    (tmp_path / "file").write_text("")
    res = _quantize(src, tiny_dataset, tmp_path / "file")
    assert res.exit_code == 1 and "not a folder" in res.output
    # a corner network that finds nothing leaves the refiner nothing to read
    quiet = tmp_path / "quiet"
    model, _, meta = load_checkpoint(src)
    save_checkpoint(quiet, model, DecodeConfig(centre_threshold=1.0), {}, load_refiner(src, meta))
    res = _quantize(quiet, tiny_dataset, tmp_path / "x")
    assert res.exit_code == 1 and "the refiner read nothing on 4 calibration frames" in res.output


def test_float_layers_name_nodes_of_the_exported_networks(quantized):
    src, _ = quantized
    det = CnnDetector.load(src, backend="onnxruntime")
    nodes = layer_nodes(det.model.onnx, ["enc1.0", "out"])  # its nodes: convolution and ReLU
    assert nodes == ["/enc1/enc1.0/enc1.0.0/Conv", "/enc1/enc1.0/enc1.0.2/Relu", "/out/Conv"]
    with pytest.raises(ValueError, match="no ONNX node belongs to module 'nothing'"):
        layer_nodes(det.model.onnx, ["nothing"])


def test_another_checkpoint_in_out_is_refused_not_overwritten(quantized, tiny_dataset, tmp_path):
    src, _ = quantized
    other = _checkpoint(tmp_path / "other")
    before = {f.name: f.read_bytes() for f in other.iterdir()}
    res = _quantize(src, tiny_dataset, other, "--images", "2")
    assert res.exit_code == 1 and "holds another checkpoint" in res.output
    assert "--detector cnn:" in res.output
    assert {f.name: f.read_bytes() for f in other.iterdir()} == before
    res = _quantize(other, tiny_dataset, other, "--images", "2")  # in place: allowed
    assert res.exit_code == 0, res.output


def test_cpu_description_names_the_model_and_the_int8_kernels(monkeypatch):
    info = "processor\t: 0\nmodel name\t: Test CPU 9000\nflags\t\t: fpu avx2\n" * 2
    monkeypatch.setattr(cnn, "_cpu_flags", lambda: info)
    monkeypatch.setattr(cnn, "native_int8", lambda: False)
    monkeypatch.setattr(cnn, "has_avx2", lambda: True)
    assert cnn.cpu_description() == "Test CPU 9000 (2 cores; int8: AVX2)"
    monkeypatch.setattr(cnn, "native_int8", lambda: True)
    assert cnn.cpu_description().endswith("int8: VNNI/AMX)")
    monkeypatch.setattr(cnn, "_cpu_flags", lambda: "")
    assert cnn.cpu_description().startswith("unknown CPU (? cores")


def test_int8_copies_without_their_weight_bits_are_refused():
    """auto decides by the bits whether this CPU computes the copies exactly, so a detector built
    from parts must be told them (a benchmark that was not ran float32 on AVX2 CPUs)."""
    with pytest.raises(ValueError, match="int8_weight_bits"):
        CnnDetector(CornerNet(TINY_MODEL).eval(), int8={"model": b"not read"})
