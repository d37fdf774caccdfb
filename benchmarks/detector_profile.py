"""Where the CNN detector's time goes: per stage, per frame, on one core, and the networks' work.

Usage::

    python benchmarks/detector_profile.py [--detector cnn[:PATH]] [--backend auto|torch|onnxruntime|int8]
                                          [--data datasets/gates-v2-test] [--frames 200] [--runs 3]
                                          [--json PATH]

Runs the stages of ``CnnDetector.detect`` one by one on the first ``--frames`` test frames (one
thread, after a warm-up pass), ``--runs`` times, and reports the median over runs of the mean ms
per frame of each stage:

- ``resize``: the frame to the corner network's input (``model.network_input``);
- ``corner_network``: the corner network (on ``--backend``; ``auto``: int8 where the checkpoint
  has int8 copies and the CPU has VNNI or AMX, else float32 ONNX Runtime);
- ``decode``: its maps to candidate gates (``decode.decode``);
- ``refiner_network``: the refiner's network calls, all readings of all candidates;
- ``refiner_rest``: the rest of ``refine.verdicts`` (patch warping, geometry, corners back to
  the image, squareness);
- ``select``: thresholds, squareness check and overlap test (``refine.select``; the check
  after the zoom stage where there is one, ``refine.keep_square``); with a rescorer, its
  features and network and the selection after it (``CnnDetector._rescored``), the zoom stage
  then reading every candidate;
- ``zoom_network`` and ``zoom_rest``: the zoom stage's network call and the rest of
  ``zoom.sharpen`` (corner patches, corners back to the image), if the detector has one.

Also counts the floating-point operations of each network per frame (PyTorch's
``FlopCounterMode``: a multiply-add is 2) and the rate the core sustained on them (GFLOP/s),
which bounds what a smaller network could save, and what a small numpy call costs right after a
network call (``cold_call_us``: the work between the networks pays this on most calls). Prints
one JSON object (also written to ``--json``) with the machine's 1-minute load average.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from importlib import import_module
from pathlib import Path

import numpy as np
import torch
from torch.utils.flop_counter import FlopCounterMode

from icarus_vision.fileio import atomic_write_json
from icarus_vision.gate_detect import make_detector
from icarus_vision.gate_detect.cnn import cpu_description
from icarus_vision.gate_detect.cnn.data import load_split, read_rgb
from icarus_vision.gate_detect.cnn.decode import decode
from icarus_vision.gate_detect.cnn.model import network_input, to_float
from icarus_vision.gate_detect.cnn.runtime import run_network
from icarus_vision.gate_detect.cnn.zoom import sharpen
from icarus_vision.gate_detect.evaluate import one_thread

# the module (the package exports a function of the same name)
refine = import_module("icarus_vision.gate_detect.cnn.refine")
DATA = Path(__file__).resolve().parents[1] / "datasets" / "gates-v2-test"
STAGES = ("resize", "corner_network", "decode", "refiner_network", "refiner_rest", "select",
          "zoom_network", "zoom_rest")  # fmt: skip


class _Timed:
    """A network wrapper that adds up the time spent in its calls and the patches it read."""

    def __init__(self, net) -> None:
        self.net, self.seconds, self.calls, self.patches = net, 0.0, 0, 0

    def run(self, *inputs):
        t0 = time.perf_counter()
        out = run_network(self.net, *inputs)
        self.seconds += time.perf_counter() - t0
        self.calls += 1
        self.patches += len(inputs[0])
        return out


def stage_times(det, images: list[np.ndarray]) -> tuple[dict, _Timed, _Timed]:
    """Mean ms per frame of each stage over ``images``, and the timed refiner and zoom stage
    (their calls)."""
    sums = dict.fromkeys(STAGES, 0.0)
    net = det.model
    refiner = _Timed(det.refiner)
    zoom = _Timed(det.zoom)
    for im in images:
        t0 = time.perf_counter()
        x = network_input(im, det.input_size)
        t1 = time.perf_counter()
        dtype = torch.bfloat16 if det.bf16 else torch.float32
        out = run_network(net, to_float(x[None]), dtype=dtype)[0]
        t2 = time.perf_counter()
        h, w = im.shape[:2]
        gates, peaks = decode(
            out, det.decode_cfg, (w / out.shape[-1], h / out.shape[-2]), with_peaks=True
        )
        t3 = time.perf_counter()
        before = refiner.seconds
        if det.rescorer is not None:  # every candidate refined and zoomed, then rescored
            v = refine.verdicts(refiner, im, gates, det.select_cfg, floor=0.0, skew=False)
            t4 = time.perf_counter()
            zoom_before = zoom.seconds
            z = sharpen(zoom, im, v.corners, det.zoom_cfg) if len(v.prob) else v.corners
            t5 = time.perf_counter()
            det._rescored(im, v.prob, v.stage, v.corners, z)
            t6 = time.perf_counter()
            net_s, zoom_s = refiner.seconds - before, zoom.seconds - zoom_before
            times = (t1 - t0, t2 - t1, t3 - t2, net_s, t4 - t3 - net_s, t6 - t5, zoom_s,
                     t5 - t4 - zoom_s)  # fmt: skip
            for k, s in zip(STAGES, times, strict=True):
                sums[k] += s
            continue
        v = refine.verdicts(refiner, im, gates, det.select_cfg, skew=det.select_cfg.max_skew > 0)
        t4 = time.perf_counter()
        found = refine.select(v, peaks, det.select_cfg, det.nms_iou)
        t5 = time.perf_counter()
        zoom_before = zoom.seconds
        if det.zoom is not None and found:
            moved = sharpen(zoom, im, np.stack([c for c, _, _ in found]), det.zoom_cfg)
            found = [(q, s, score) for q, (_, s, score) in zip(moved, found, strict=True)]
        t6 = time.perf_counter()
        if det.select_cfg is not det.refine_cfg:  # the squareness check on the zoomed corners
            refine.keep_square(found, (w, h), det.refine_cfg)
        t7 = time.perf_counter()
        net_s, zoom_s = refiner.seconds - before, zoom.seconds - zoom_before
        times = (t1 - t0, t2 - t1, t3 - t2, net_s, t4 - t3 - net_s, t5 - t4 + t7 - t6, zoom_s,
                 t6 - t5 - zoom_s)  # fmt: skip
        for k, s in zip(STAGES, times, strict=True):
            sums[k] += s
    return {k: 1000.0 * v / len(images) for k, v in sums.items()}, refiner, zoom


def network_flops(spec: str) -> dict:
    """Floating-point operations of one corner-network frame and one refiner patch (the
    float32 modules of the checkpoint of ``spec``)."""
    from icarus_vision.gate_detect.cnn.checkpoint import (
        SHIPPED,
        load_checkpoint,
        load_refiner,
        load_zoom,
    )

    path = spec.partition(":")[2] or SHIPPED
    model, _, meta = load_checkpoint(path)
    refiner = load_refiner(path, meta)
    w, h = model.cfg.input_size
    p = refiner.cfg.patch
    out = {}
    with torch.no_grad():
        with FlopCounterMode(display=False) as fc:
            model.eval()(torch.zeros(1, 3, h, w))
        out["corner_network"] = fc.get_total_flops()
        with FlopCounterMode(display=False) as fc:
            refiner.eval()(torch.zeros(1, 3, p, p), torch.zeros(1, refiner.cfg.num_geom))
        out["refiner_patch"] = fc.get_total_flops()
        zoom = load_zoom(path, meta)
        if zoom is not None:
            with FlopCounterMode(display=False) as fc:
                zoom.eval()(torch.zeros(1, 3, zoom.cfg.patch, zoom.cfg.patch))
            out["zoom_patch"] = fc.get_total_flops()
    return out


def cold_call_us(det, repeats: int = 300) -> dict:
    """Median µs of one small numpy operation (a (2, 3, 3) sum) right after a refiner network
    call, and of the same operation called again at once: what the first call after a network
    costs once the network's weights have evicted the caches."""
    p = det.refine_cfg.patch
    x = np.zeros((4, 3, p, p), np.float32)
    g = np.zeros((4, det.refine_cfg.num_geom), np.float32)
    h = np.ones((2, 3, 3))
    cold, warm = [], []
    for _ in range(repeats):
        run_network(det.refiner, x, g)
        for times in (cold, warm):
            t0 = time.perf_counter()
            h.sum(axis=1)
            times.append(time.perf_counter() - t0)
    return {k: round(1e6 * float(np.median(v)), 1) for k, v in (("cold", cold), ("warm", warm))}


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--detector", default="cnn")
    ap.add_argument("--backend", default="auto", help="auto, torch, onnxruntime or int8")
    ap.add_argument("--data", type=Path, default=DATA)
    ap.add_argument("--frames", type=int, default=200)
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args(argv)
    if not (args.data / "annotations" / "test.json").is_file():
        sys.exit(f"{args.data}: no dataset; generate it first (see benchmarks/detector.py)")
    det = make_detector(args.detector, backend=args.backend)
    if getattr(det, "refiner", None) is None:
        sys.exit(f"{args.detector}: not a CNN detector with a refiner")
    images = [read_rgb(f) for f in load_split(args.data, "test", None, args.frames).files]
    runs = []
    with one_thread():
        stage_times(det, images[:20])  # warm-up
        for _ in range(args.runs):
            runs.append(stage_times(det, images))
        numpy_call = cold_call_us(det)
    per_stage = {k: round(float(np.median([r[0][k] for r in runs])), 3) for k in STAGES}
    refiner, zoom = runs[0][1], runs[0][2]
    flops = network_flops(args.detector)
    patches = refiner.patches / len(images)
    mflop = {"corner_network": flops["corner_network"] / 1e6,
             "refiner_network": flops["refiner_patch"] * patches / 1e6}  # fmt: skip
    if "zoom_patch" in flops and per_stage["zoom_network"] > 0:
        mflop["zoom_network"] = flops["zoom_patch"] * zoom.patches / len(images) / 1e6
    out = {
        "detector": args.detector,
        "frames": len(images),
        "runs": args.runs,
        "cpu": cpu_description(),
        "load_avg_1min": round(os.getloadavg()[0], 2),
        "backend": det.backend,
        "bf16": det.bf16,
        "ms_per_frame": per_stage | {"total": round(sum(per_stage.values()), 3)},
        "refiner_calls_per_frame": round(refiner.calls / len(images), 2),
        "refiner_patches_per_frame": round(patches, 2),
        "zoom_patches_per_frame": round(zoom.patches / len(images), 2),
        "mflop_per_frame": {k: round(v, 1) for k, v in mflop.items()},
        "gflop_per_s": {k: round(v / per_stage[k], 1) for k, v in mflop.items()},
        "numpy_call_us_after_network": numpy_call,
    }
    for k in (*STAGES, "total"):
        print(f"{k:16} {out['ms_per_frame'][k]:7.2f} ms")
    for k in mflop:
        print(
            f"{k:16} {out['mflop_per_frame'][k]:7.1f} MFLOP/frame, {out['gflop_per_s'][k]} GFLOP/s"
        )
    print(
        f"a numpy call right after a network: {numpy_call['cold']} µs ({numpy_call['warm']} µs again)"
    )
    print(json.dumps(out))
    if args.json is not None:
        atomic_write_json(args.json, out)
    return out


if __name__ == "__main__":
    main()
