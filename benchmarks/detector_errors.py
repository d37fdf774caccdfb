"""Where a detector's errors come from: false positives, misses and far corners by kind.

Usage::

    python benchmarks/detector_errors.py [--detector cnn] [--data datasets/gates-v2-20k]
                                         [--split val] [--limit N]

Counts, over the counted gates (the eval-detector rule: mean side >= 20 px, four corners in the
image, three visible):

- false positives that overlap no labelled gate (IoU < 0.05 with each) and those that overlap one
  but were not matched (corners too far off);
- misses with no detection near them (IoU < 0.3 with each) and those with a detection over them
  whose corners are wrong;
- matched corners more than 5 px from the truth (with the misses' corners, what PCK@5px loses).

Prints one JSON object. The split defaults to the training data's val split, so the test split
stays for the figures in the README.
"""

from __future__ import annotations

import argparse
import collections
import json
from pathlib import Path

import numpy as np

from icarus_vision.gate_detect import make_detector
from icarus_vision.gate_detect.cnn.data import load_split, read_rgb
from icarus_vision.gate_detect.cnn.polygon import quad_iou
from icarus_vision.gate_detect.metrics import evaluate_image

DATA = Path(__file__).resolve().parents[1] / "datasets" / "gates-v2-20k"
MIN_GATE_PX = 20.0


def error_kinds(detector: str, data: Path, split: str, limit: int | None = None) -> dict:
    """Counts of each kind of error of ``detector`` on ``split`` (see the module docstring)."""
    det = make_detector(detector)
    d = load_split(data, split, None, limit)
    c: collections.Counter = collections.Counter()
    for path, gates in zip(d.files, d.gates, strict=True):
        found = det.detect(read_rgb(path))
        truth = [(g.corners, g.visibility, g.distance) for g in gates]
        g_rec, p_rec = evaluate_image([(f.corners, f.score) for f in found], truth, MIN_GATE_PX)
        labelled = [g.corners for g in gates if np.isfinite(g.corners).all()]
        for f, p in zip(found, p_rec, strict=True):
            if p["status"] == "fp":
                near = max((quad_iou(f.corners, t) for t in labelled), default=0.0)
                c["fp_on_nothing" if near < 0.05 else "fp_wrong_corners"] += 1
        for g in g_rec:
            if not (g["evaluable"] and g["side"] >= MIN_GATE_PX):
                continue
            c["gates"] += 1
            if g["matched"]:
                c["matched_corners"] += 4
                c["corners_over_5px"] += int((g["errors"] > 5.0).sum())
                continue
            near = max((quad_iou(f.corners, g["corners"]) for f in found), default=0.0)
            c["miss_nothing_near" if near < 0.3 else "miss_wrong_corners"] += 1
    return {"detector": detector, "split": split, "images": len(d.files), **c}


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--detector", default="cnn")
    ap.add_argument("--data", type=Path, default=DATA)
    ap.add_argument("--split", default="val")
    ap.add_argument("--limit", type=int, default=None, help="Only the first N images.")
    args = ap.parse_args(argv)
    out = error_kinds(args.detector, args.data, args.split, args.limit)
    print(json.dumps(out, indent=2))
    return out


if __name__ == "__main__":
    main()
