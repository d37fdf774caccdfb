"""The CNN gate-corner detector (``make_detector("cnn")`` or ``"cnn:PATH"``).

The network (``model.py``) predicts gate-centre and corner heatmaps at a quarter of the camera
resolution; ``decode.py`` groups corners into candidate gates. An optional second stage
(``refine.py``) rectifies each candidate into a small patch (``rectify.py``), verifies it and
corrects its corners; an optional third (``zoom.py``) reads each corner of a large gate again,
zoomed in; an optional fourth (``rescore.py``) scores every candidate again from what the others
measured. ``runtime.py`` runs the networks (ONNX Runtime or PyTorch) on numpy arrays.
``train.py`` trains the first stage on gen-dataset output, ``refine_train.py`` the second,
``zoom_train.py`` the third; ``checkpoint.py`` saves them as safetensors + JSON. The shipped
default lives in ``icarus_vision/models/detector/``.
"""

from __future__ import annotations

import copy
import functools
import warnings
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch
from torch import nn

from icarus_vision.gate_detect.base import Detector, GateDetection, validate_image
from icarus_vision.gate_detect.cnn.checkpoint import (
    SHIPPED,
    int8_weight_bits,
    load_checkpoint,
    load_int8,
    load_refiner,
    load_rescorer,
    load_zoom,
)
from icarus_vision.gate_detect.cnn.decode import DecodeConfig, decode, in_frame
from icarus_vision.gate_detect.cnn.model import CornerNet, letterbox_size, network_input, to_float
from icarus_vision.gate_detect.cnn.refine import (
    RefineNet,
    keep_square,
    non_overlapping,
    refine,
    square_enough,
    verdicts,
)
from icarus_vision.gate_detect.cnn.rescore import FEATURES, RescoreNet, features
from icarus_vision.gate_detect.cnn.runtime import OnnxRuntimeNet, run_network
from icarus_vision.gate_detect.cnn.zoom import ZoomNet, sharpen
from icarus_vision.gate_detect.registry import register_detector


def fuse_batchnorm(model: nn.Module) -> nn.Module:
    """Fold every Conv2d -> BatchNorm2d pair of ``model`` (eval mode) into the convolution."""
    for module in model.modules():
        if not isinstance(module, nn.Sequential):
            continue
        for i in range(len(module) - 1):
            conv, bn = module[i], module[i + 1]
            if isinstance(conv, nn.Conv2d) and isinstance(bn, nn.BatchNorm2d):
                module[i] = torch.nn.utils.fusion.fuse_conv_bn_eval(conv, bn)
                module[i + 1] = nn.Identity()
    return model


def frozen_trace(model: nn.Module, example: torch.Tensor | tuple) -> nn.Module:
    """``model`` traced on ``example`` (B, 3, H, W), or a tuple of its inputs, and frozen by
    TorchScript, or ``model`` itself if that fails.

    Freezing makes the weights constants of one graph, run without the Python calls of the
    modules: the outputs are identical, and a frame takes 0.2-0.7 ms less on one core (the README's
    figures). Tracing and freezing take about 0.1 s (the detector does it when built). TorchScript
    is deprecated in favour of ``torch.compile``, which needs a C++ compiler and tens of seconds at
    start-up; with torch pinned, tracing stays the cheaper way.
    """
    try:
        with warnings.catch_warnings(), torch.no_grad():
            warnings.simplefilter("ignore")
            return torch.jit.freeze(torch.jit.trace(model.eval(), example, check_trace=False))
    except Exception:  # noqa: BLE001 - any tracing failure: run the module as it is
        return model


BACKENDS = ("auto", "torch", "onnxruntime", "int8")
"""What runs the networks (:class:`CnnDetector`'s ``backend``)."""


def _cpu_flags() -> str:
    """This CPU's flags (Linux /proc/cpuinfo; empty elsewhere)."""
    try:
        return Path("/proc/cpuinfo").read_text()
    except OSError:
        return ""


@functools.cache
def native_bf16() -> bool:
    """Whether this CPU computes in bfloat16 natively (AVX512-BF16 or AMX; Linux /proc/cpuinfo)."""
    flags = _cpu_flags()
    return "avx512_bf16" in flags or "amx_bf16" in flags


@functools.cache
def native_int8() -> bool:
    """Whether this CPU has 8-bit dot products (AVX512-VNNI, AVX-VNNI or AMX; Linux
    /proc/cpuinfo): ONNX Runtime's int8 kernels then sum in 32 bits."""
    flags = _cpu_flags()
    return any(f in flags for f in ("avx512_vnni", "avx_vnni", "amx_int8"))


@functools.cache
def has_avx2() -> bool:
    """Whether this CPU has AVX2 (Linux /proc/cpuinfo): ONNX Runtime's int8 kernels there add
    pairs of products in 16 bits, exact only for weights of at most 7 bits (``quantize.py``)."""
    return "avx2" in _cpu_flags().split()


def cpu_description() -> str:
    """This CPU's model name and what its int8 kernels use (VNNI or AMX, AVX2, neither), for
    benchmark reports: the detector's speed depends on both (Linux /proc/cpuinfo; "unknown CPU"
    elsewhere)."""
    names = [line.split(":", 1)[1].strip() for line in _cpu_flags().splitlines()
             if line.startswith("model name")]  # fmt: skip
    kernels = "VNNI/AMX" if native_int8() else "AVX2" if has_avx2() else "no AVX2"
    return f"{names[0] if names else 'unknown CPU'} ({len(names) or '?'} cores; int8: {kernels})"


def int8_runs_exactly(weight_bits: int) -> bool:
    """Whether this CPU computes int8 copies with ``weight_bits``-bit weights without
    saturating a sum: with 8-bit dot products any, with AVX2 7-bit ones. ``auto`` runs int8
    only then (else float32), so the detector's output is the same on every such CPU."""
    return native_int8() or (weight_bits <= 7 and has_avx2())


class CnnDetector(Detector):
    """Gates found by the corner network.

    Args:
        model: a trained :class:`CornerNet` (put in eval mode; batch norm folded for speed).
        decode_cfg: decoding thresholds.
        threads: if not None, set PyTorch's (process-wide) intra-op thread count to this when
            the detector is built. 1 by default: this small network gains nothing from more
            threads, and threads contending with other work on a busy machine can slow every
            frame down many times (switching per call costs more than the inference itself).
        bf16: run the corner network in bfloat16 on the torch backend (it was trained under
            bfloat16 autocast); None: where the CPU has bfloat16 arithmetic (:func:`native_bf16`)
            and the backend is torch. Decoding stays float32.
        frozen: run a TorchScript-frozen trace of the network (:func:`frozen_trace`): the same
            output, faster.
        refiner: a trained second stage (:class:`RefineNet`): ``decode_cfg`` then yields its
            candidates, and it decides which are gates and where their corners are. It runs in
            float32 (frozen when ``frozen``).
        backend: "torch" (PyTorch, frozen when ``frozen``), "onnxruntime" (the networks
            exported to ONNX when the detector is built, about a second, and run by ONNX
            Runtime in float32), "int8" (ONNX Runtime running the int8 copies in ``int8``) or
            "auto": "torch" when ``bf16`` is True, else "int8" where there are int8 copies the
            CPU computes exactly (:func:`int8_runs_exactly`), else "onnxruntime" (README:
            Detection, for what each costs).
        int8: int8 ONNX copies of the networks by name (``model``, ``refiner``, ``zoom``; from
            ``quantize.py`` via :func:`~icarus_vision.gate_detect.cnn.checkpoint.load_int8`),
            each for the network of the same weights passed here.
        int8_weight_bits: bits of those copies' weights (the checkpoint's ``int8`` section
            records them, :func:`~icarus_vision.gate_detect.cnn.checkpoint.int8_weight_bits`;
            copies made before it did have 8). Required with ``int8``: ``auto`` decides by it
            whether this CPU computes the copies exactly.
        zoom: a trained third stage (:class:`ZoomNet`): it reads each corner of every reported
            gate at least ``zoom.cfg.min_side_px`` across again, zoomed in, and moves it. It
            runs as the refiner does. The refiner's squareness check (``max_skew``) then takes
            the zoomed corners, the more precise ones (on val, a little more precision:
            docs/history/detector.md).
        rescorer: a trained fourth stage (:class:`RescoreNet`, needs ``refiner`` and ``zoom``):
            every candidate is refined and zoomed, and the rescorer's probability replaces the
            refiner's score (its own threshold, then the same overlap, squareness and frame
            checks).
        min_score: report only the gates scored at least this (None: every gate the stages
            keep): fewer false gates for fewer found, as a detector's confidence threshold.
            With a rescorer the score is its probability (the shipped detector keeps 0.35 and
            up; on the real Cyberzoo frames 0.95 gave precision 0.95 at recall 0.56).
    """

    name = "cnn"

    def __init__(
        self,
        model: CornerNet,
        decode_cfg: DecodeConfig = DecodeConfig(),
        threads: int | None = 1,
        bf16: bool | None = None,
        frozen: bool = True,
        refiner: RefineNet | None = None,
        backend: str = "auto",
        zoom: ZoomNet | None = None,
        int8: dict[str, bytes] | None = None,
        int8_weight_bits: int | None = None,
        rescorer: RescoreNet | None = None,
        min_score: float | None = None,
    ) -> None:
        if min_score is not None and not 0.0 <= min_score <= 1.0:
            raise ValueError(f"min_score must be in [0, 1] or None, got {min_score}")
        if rescorer is not None and (refiner is None or zoom is None):
            raise ValueError("a rescorer needs the refiner and the zoom stage it was trained on")
        if backend not in BACKENDS:
            raise ValueError(f"backend must be one of {BACKENDS}, got {backend!r}")
        if int8 and int8_weight_bits is None:
            raise ValueError(
                "int8 copies need int8_weight_bits (checkpoint.int8_weight_bits of the "
                "checkpoint's metadata): auto runs them only where the CPU computes them exactly"
            )
        needed = {"model"} | {k for k, v in (("refiner", refiner), ("zoom", zoom)) if v is not None}
        if backend == "int8" and not needed <= set(int8 or {}):
            raise ValueError(
                f"the int8 backend needs int8 copies of {sorted(needed)} (icarus-vision "
                f"quantize-detector), got {sorted(int8 or {})}"
            )
        # Folded batch norm and channels-last memory: about 1.4x faster on a CPU core.
        self._float32 = fuse_batchnorm(model.eval()).to(memory_format=torch.channels_last)
        self._nets: dict = {}  # by (bf16, frozen), or "onnxruntime" or "int8"
        if threads is not None and torch.get_num_threads() != threads:
            torch.set_num_threads(threads)
        self.decode_cfg = decode_cfg
        self.nms_iou = decode_cfg.nms_iou  # of the output (with a refiner, not its candidates')
        self.max_outside_px = decode_cfg.max_outside_px  # likewise
        self.input_size = tuple(model.cfg.input_size)
        if backend in ("onnxruntime", "int8") and bf16:
            raise ValueError("bf16 runs on the torch backend only")
        if backend == "auto":
            if bf16:
                backend = "torch"
            elif needed <= set(int8 or {}) and int8_runs_exactly(int8_weight_bits):
                backend = "int8"
            else:
                backend = "onnxruntime"
        if bf16 is None:
            bf16 = backend == "torch" and native_bf16()
        self.bf16 = bool(bf16)
        self.int8 = int8 if backend == "int8" else None
        self.backend = backend
        self.threads = threads
        self.frozen = frozen
        _ = self.model  # build (and trace) it now rather than in the first frame's time
        self.refine_cfg = None if refiner is None else refiner.cfg
        self.refiner = None
        if refiner is not None:
            # No candidate whose centre scores under the refiner's threshold can pass it (its
            # score is at most the centre's), so none is decoded: the same output, faster. A
            # rescorer has its own threshold and reads every candidate.
            floor = decode_cfg.centre_threshold
            if rescorer is None:
                floor = max(floor, refiner.cfg.threshold)
            self.decode_cfg = replace(
                decode_cfg, centre_threshold=floor, nms_iou=refiner.cfg.candidate_iou
            )
            p = refiner.cfg.patch
            example = (torch.zeros(2, p, p, 3).permute(0, 3, 1, 2),
                       torch.zeros(2, refiner.cfg.num_geom))  # fmt: skip
            self.refiner = self._runner(refiner, example, "refiner")
        self.zoom_cfg = None if zoom is None else zoom.cfg
        self.zoom = None
        # With a zoom stage, the squareness check waits for its corners (:meth:`detect_batch`).
        self.select_cfg = self.refine_cfg
        if zoom is not None and refiner is not None:
            self.select_cfg = replace(refiner.cfg, max_skew=0.0)
        if zoom is not None:
            p = zoom.cfg.patch
            self.zoom = self._runner(zoom, (torch.zeros(2, p, p, 3).permute(0, 3, 1, 2),), "zoom")
        self.rescorer = None if rescorer is None else rescorer.eval()
        self.min_score = min_score

    def _runner(self, net: nn.Module, example: tuple, name: str) -> nn.Module | OnnxRuntimeNet:
        """A patch network as the backend runs it: its int8 copy ``name``; else batch norm
        folded, channels-last (faster on a CPU core; it reads contiguous patches too), then
        exported to ONNX Runtime or frozen (:attr:`frozen`) on ``example`` inputs."""
        if self.backend == "int8":
            return OnnxRuntimeNet.from_onnx(self.int8[name], self.threads, f"int8 {name}")
        net = fuse_batchnorm(copy.deepcopy(net).eval()).to(memory_format=torch.channels_last)
        if self.backend == "onnxruntime":
            return OnnxRuntimeNet(net, example, self.threads)
        return frozen_trace(net, example) if self.frozen else net

    @property
    def model(self) -> nn.Module | OnnxRuntimeNet:
        """The network that runs (built on first use of each setting): an
        :class:`OnnxRuntimeNet` on that backend; else a bfloat16 copy when :attr:`bf16` (weights
        cast once, not per call as autocast would; about 0.3 ms less per frame), else the
        float32 one; frozen when :attr:`frozen`."""
        if self.backend == "int8":
            if "int8" not in self._nets:
                model = self.int8["model"]
                self._nets["int8"] = OnnxRuntimeNet.from_onnx(model, self.threads, "int8 model")
            return self._nets["int8"]
        if self.backend == "onnxruntime":
            if "onnxruntime" not in self._nets:
                w, h = self.input_size
                example = (torch.zeros(1, 3, h, w),)
                self._nets["onnxruntime"] = OnnxRuntimeNet(self._float32, example, self.threads)
            return self._nets["onnxruntime"]
        key = (self.bf16, self.frozen)
        if key not in self._nets:
            net = self._float32
            if self.bf16:
                net = copy.deepcopy(net).to(torch.bfloat16)
            if self.frozen:
                w, h = self.input_size
                dtype = torch.bfloat16 if self.bf16 else torch.float32
                net = frozen_trace(net, torch.zeros(1, 3, h, w, dtype=dtype))
            self._nets[key] = net
        return self._nets[key]

    @classmethod
    def load(
        cls,
        path: str | Path | None = None,
        *,
        threads: int | None = 1,
        bf16: bool | None = None,
        frozen: bool = True,
        backend: str = "auto",
        min_score: float | None = None,
    ) -> CnnDetector:
        """From a checkpoint folder or file (None: the shipped default), with its int8 copies
        if it has them; the settings as the constructor's."""
        path = SHIPPED if path is None else path
        model, decode_cfg, meta = load_checkpoint(path)
        refiner, zoom = load_refiner(path, meta), load_zoom(path, meta)
        return cls(model, decode_cfg, refiner=refiner, zoom=zoom, int8=load_int8(path, meta),
                   int8_weight_bits=int8_weight_bits(meta), threads=threads, bf16=bf16,
                   frozen=frozen, backend=backend, rescorer=load_rescorer(path, meta),
                   min_score=min_score)  # fmt: skip

    def detect_batch(self, images: list[np.ndarray]) -> list[list[GateDetection]]:
        """:meth:`detect` of several (H, W, 3) uint8 RGB images in one forward pass; with
        :attr:`min_score`, only the gates scored at least that."""
        found = self._detect_batch(images)
        if self.min_score is None:
            return found
        return [[d for d in frame if d.score >= self.min_score] for frame in found]

    def _detect_batch(self, images: list[np.ndarray]) -> list[list[GateDetection]]:
        results = []
        for im, o, scale in self._corner_maps(images):
            h, w = im.shape[:2]
            if self.rescorer is not None:
                results.append(self._rescored(im, *self._candidates(im, o, scale)))
                continue
            if self.refiner is None:
                found = decode(o, self.decode_cfg, scale)
            else:
                cand, peaks = decode(o, self.decode_cfg, scale, with_peaks=True)
                found = refine(self.refiner, im, cand, peaks, self.select_cfg, self.nms_iou)
            if self.zoom is not None and found:
                moved = sharpen(self.zoom, im, np.stack([c for c, _, _ in found]), self.zoom_cfg)
                found = [(q, s, score) for q, (_, s, score) in zip(moved, found, strict=True)]
                if self.select_cfg is not self.refine_cfg:
                    found = keep_square(found, (w, h), self.refine_cfg)
            if self.refiner is not None:  # decode checked the corner network's own gates
                found = in_frame(found, (w, h), self.max_outside_px)
            results.append([GateDetection(c, s, score) for c, s, score in found])
        return results

    def _corner_maps(self, images: list[np.ndarray]):
        """Per image (validated): (image, the corner network's maps, their scale to the image's
        pixels (x, y)), the network run once on all of them. A frame of another aspect ratio
        than the network's input is letterboxed (:func:`network_input`), not stretched."""
        images = [validate_image(im) for im in images]
        if not images:
            return []
        x = to_float(np.stack([network_input(im, self.input_size) for im in images]))
        out = run_network(self.model, x, dtype=torch.bfloat16 if self.bf16 else torch.float32)
        maps = []
        for im, o in zip(images, out, strict=True):
            w, h = letterbox_size(im.shape[1::-1], self.input_size)  # padded at right / bottom
            maps.append((im, o, (w / o.shape[-1], h / o.shape[-2])))
        return maps

    def _candidates(self, image: np.ndarray, out: np.ndarray, scale: tuple[float, float]):
        """Every candidate of one frame read by the refiner and the zoom stage: (refiner
        probabilities (N,), first-stage scores (N,), refined corners (N, 4, 2), zoomed corners
        (N, 4, 2)); ``out`` is the corner network's output for it."""
        cand, _ = decode(out, self.decode_cfg, scale, with_peaks=True)
        v = verdicts(self.refiner, image, cand, self.select_cfg, floor=0.0, skew=False)
        zoomed = sharpen(self.zoom, image, v.corners, self.zoom_cfg) if len(v.prob) else v.corners
        return v.prob, v.stage, v.corners, zoomed

    def candidate_table(self, image: np.ndarray):
        """What the rescorer reads about each candidate of one (H, W, 3) uint8 RGB frame:
        (features (N, F), zoomed corners (N, 4, 2)) (``train-rescorer`` learns from these)."""
        if self.refiner is None or self.zoom is None:
            raise ValueError("candidate_table needs a detector with a refiner and a zoom stage")
        image, o, scale = self._corner_maps([image])[0]
        prob, stage, refined, zoomed = self._candidates(image, o, scale)
        return features(prob, stage, refined, zoomed, image.shape[1::-1]), zoomed

    def _rescored(self, image, prob, stage, refined, zoomed) -> list[GateDetection]:
        """One frame's gates by the rescorer's probability: at least its threshold, best first,
        none overlapping a better one by more than ``nms_iou`` (refined corners), then the
        squareness check (zoomed corners, rescored) and the frame's edge."""
        if not len(prob):
            return []
        h, w = image.shape[:2]
        x = features(prob, stage, refined, zoomed, (w, h))
        p = self.rescorer.probabilities(x)
        order = np.argsort(-p, kind="stable")
        order = order[p[order] >= self.rescorer.cfg.threshold]
        kept = order[non_overlapping(refined[order], self.nms_iou)]
        if not len(kept):
            return []
        z = zoomed[kept]
        skew = x[kept, FEATURES.index("skew_zoom")]  # :func:`skews` of the zoomed corners
        square = square_enough(skew, z, p[kept], self.refine_cfg)
        found = [(z[j], np.full(4, p[i]), float(p[i])) for j, i in enumerate(kept) if square[j]]
        found = in_frame(found, (w, h), self.max_outside_px)
        return [GateDetection(c, s, score) for c, s, score in found]

    def _detect(self, image: np.ndarray) -> list[GateDetection]:
        return self.detect_batch([image])[0]


register_detector("cnn", CnnDetector.load)
