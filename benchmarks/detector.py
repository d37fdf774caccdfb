"""Gate-detector speed and accuracy: ms per frame on one core, and the eval-detector figures.

Usage::

    icarus-vision gen-dataset --recipe datasets/gates-v1.toml --out datasets/gates-v2-test \\
        --num-images 10000 --seed 1        # held out: the shipped CNN was trained on seed 0
    python benchmarks/detector.py [--data datasets/gates-v2-test] [--detectors cnn opencv]
                                  [--limit N] [--json PATH] [--backend-rounds N]

For each detector: the test-split figures of ``eval_detector`` (precision, recall, corner error,
PCK, by distance, and their 95 % bootstrap intervals over the test images) and a latency run:
``detect`` on the first 50 test frames, 5 passes, on one thread, reporting the median and 95th
percentile ms per frame; for a CNN, also
``--backend-rounds`` alternating runs on each backend, PyTorch (in bfloat16 where the CPU has it),
ONNX Runtime in float32 and, where the checkpoint has int8 copies (``quantize-detector``), ONNX
Runtime in int8 (the median of their medians); ``backend`` is the one ``auto`` chose. Prints a
table and one JSON object (also written to ``--json``). The machine's 1-minute load average is
recorded: timings on a busy machine are slower than on an idle core.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

from icarus_vision.fileio import atomic_write_json
from icarus_vision.gate_detect import make_detector
from icarus_vision.gate_detect.cnn import cpu_description
from icarus_vision.gate_detect.cnn.data import load_split, read_rgb
from icarus_vision.gate_detect.evaluate import eval_detector, one_thread

DATA = Path(__file__).resolve().parents[1] / "datasets" / "gates-v2-test"


def latency(spec: str, data: Path, frames: int = 50, passes: int = 5, backend=None) -> dict:
    """Median and p95 ms per ``detect`` call on one thread."""
    det = make_detector(spec, **({} if backend is None else {"backend": backend}))
    split = load_split(data, "test", None, frames)
    images = [read_rgb(f) for f in split.files]
    times = []
    with one_thread():
        for im in images[:5]:
            det.detect(im)  # warm-up
        for _ in range(passes):
            for im in images:
                t0 = time.perf_counter()
                det.detect(im)
                times.append(1000.0 * (time.perf_counter() - t0))
    return {"median_ms": round(float(np.median(times)), 3),
            "p95_ms": round(float(np.percentile(times, 95)), 3)}  # fmt: skip


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--data", type=Path, default=DATA)
    ap.add_argument("--detectors", nargs="+", default=["cnn", "opencv"])
    ap.add_argument("--limit", type=int, default=None, help="Evaluate the first N test images.")
    ap.add_argument("--json", type=Path, default=None)
    ap.add_argument(
        "--backend-rounds",
        type=int,
        default=3,
        help="Alternating latency runs of each CNN backend (torch, onnxruntime, int8).",
    )
    args = ap.parse_args(argv)
    if not (args.data / "annotations" / "test.json").is_file():
        sys.exit(f"{args.data}: no dataset; generate it first (see this script's docstring)")
    out = {"data": str(args.data), "cpu": cpu_description(),
           "load_avg_1min": round(os.getloadavg()[0], 2), "detectors": {}}  # fmt: skip
    for spec in args.detectors:
        r = eval_detector(args.data, spec, limit=args.limit)
        keep = ("images", "gates", "min_gate_px", "precision", "recall", "corner_error_px", "pck",
                "confidence", "ms_per_frame", "by_distance", "by_size", "backend")  # fmt: skip
        out["detectors"][spec] = {k: r[k] for k in keep} | {"latency": latency(spec, args.data)}
        if spec.split(":")[0] == "cnn":  # every backend, alternating (the machine's load drifts)
            backends = ["torch", "onnxruntime"]
            try:
                make_detector(spec, backend="int8")
                backends.append("int8")
            except ValueError:  # no int8 copies in this checkpoint
                pass
            runs = {b: [] for b in backends}
            for _ in range(args.backend_rounds):
                for b in runs:
                    runs[b].append(latency(spec, args.data, backend=b)["median_ms"])
            out["detectors"][spec]["latency_by_backend_ms"] = {
                b: {"median_of_medians": round(float(np.median(v)), 3), "runs": v}
                for b, v in runs.items()
            }
    print(f"CPU: {out['cpu']}")
    print(f"{'detector':10} {'gates':>6} {'prec':>6} {'recall':>6} {'med px':>7} {'mean px':>7} "
          f"{'PCK2':>6} {'PCK5':>6} {'ms p50':>7} {'ms p95':>7}")  # fmt: skip
    for spec, r in out["detectors"].items():
        f = [r["precision"], r["recall"], r["corner_error_px"]["median"],
             r["corner_error_px"]["mean"], r["pck"]["2px"], r["pck"]["5px"]]  # fmt: skip
        cells = " ".join(f"{'-' if x is None else f'{x:.3f}':>6}" for x in f)
        lat = r["latency"]
        print(f"{spec:10} {r['gates']:>6} {cells} {lat['median_ms']:>7.2f} {lat['p95_ms']:>7.2f}"
              + (f"  ({r['backend']})" if r["backend"] else ""))  # fmt: skip
        ci = r["confidence"]
        print("  95 % intervals (bootstrap over images): " + ", ".join(
            f"{k} {v[0]:.4f}-{v[1]:.4f}" for k, v in ci.items() if isinstance(v, list)))  # fmt: skip
        for b, v in r.get("latency_by_backend_ms", {}).items():
            print(f"  {b}: {v['median_of_medians']:.2f} ms per frame (median of {v['runs']})")
    print(json.dumps(out))
    if args.json is not None:
        atomic_write_json(args.json, out)
    return out


if __name__ == "__main__":
    main()
