"""Two CNN detectors' latency, alternated: what one change costs per frame on one core.

Usage::

    python benchmarks/detector_ab.py [--a cnn] [--b cnn] [--b-without-zoom]
                                     [--data datasets/gates-v2-test] [--frames 200]
                                     [--rounds 8] [--passes 3] [--json PATH]

The machine's speed drifts by up to a third within minutes, so two detectors timed minutes apart
are not comparable. This builds both in one process and alternates them: each round times
``detect`` on the first ``--frames`` test frames, ``--passes`` times, for each detector (the
order swapped every round), on one thread, after a warm-up. Reports each detector's median ms
per frame of every round, the median over rounds, and each round's difference (A - B).
``--b-without-zoom`` builds B from the same checkpoint as ``--b`` with its zoom stage left out
(what the zoom stage costs). Prints one JSON object (also written to ``--json``).
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
from icarus_vision.gate_detect.cnn.data import load_split, read_rgb
from icarus_vision.gate_detect.evaluate import one_thread

DATA = Path(__file__).resolve().parents[1] / "datasets" / "gates-v2-test"


def round_ms(det, images: list[np.ndarray], passes: int) -> float:
    """Median ms of one ``detect`` call over ``passes`` passes of ``images``."""
    times = []
    for _ in range(passes):
        for im in images:
            t0 = time.perf_counter()
            det.detect(im)
            times.append(time.perf_counter() - t0)
    return 1000.0 * float(np.median(times))


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--a", default="cnn", help="Detector A (cnn[:PATH]).")
    ap.add_argument("--b", default="cnn", help="Detector B (cnn[:PATH]).")
    ap.add_argument("--b-without-zoom", action="store_true", help="B without its zoom stage.")
    ap.add_argument("--data", type=Path, default=DATA)
    ap.add_argument("--frames", type=int, default=200)
    ap.add_argument("--rounds", type=int, default=8)
    ap.add_argument("--passes", type=int, default=3)
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args(argv)
    if not (args.data / "annotations" / "test.json").is_file():
        sys.exit(f"{args.data}: no dataset; generate it first (see benchmarks/detector.py)")
    images = [read_rgb(f) for f in load_split(args.data, "test", None, args.frames).files]
    dets = {"a": make_detector(args.a), "b": make_detector(args.b)}
    if args.b_without_zoom:
        dets["b"].zoom = None
    ms: dict[str, list[float]] = {"a": [], "b": []}
    with one_thread():
        for det in dets.values():
            round_ms(det, images[:30], 1)  # warm-up
        for r in range(args.rounds):
            for k in ("a", "b") if r % 2 == 0 else ("b", "a"):
                ms[k].append(round_ms(dets[k], images, args.passes))
    out = {
        "a": args.a,
        "b": args.b + (" without zoom" if args.b_without_zoom else ""),
        "frames": len(images),
        "load_avg_1min": round(os.getloadavg()[0], 2),
        "median_ms": {k: round(float(np.median(v)), 2) for k, v in ms.items()},
        "rounds_ms": {k: [round(x, 2) for x in v] for k, v in ms.items()},
        "a_minus_b_ms": [round(x - y, 2) for x, y in zip(ms["a"], ms["b"], strict=True)],
    }
    print(f"A {out['a']}: {out['median_ms']['a']} ms; B {out['b']}: {out['median_ms']['b']} ms")
    print(json.dumps(out))
    if args.json is not None:
        atomic_write_json(args.json, out)
    return out


if __name__ == "__main__":
    main()
