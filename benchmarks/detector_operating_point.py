"""The CNN detector's operating point: its figures on val splits at each refiner threshold and
out-of-frame margin, from one run of the detector (with a rescorer, its threshold is the one
varied).

Usage::

    python benchmarks/detector_operating_point.py [--detector cnn[:PATH]] [--backend auto|int8|onnxruntime]
        [--data datasets/gates-v2-ft12 --data datasets/gates-v2-test5] [--split val]
        [--thresholds 0.15 0.2 0.25 0.3 0.35] [--outside none 0.5 1.5 3]
        [--max-skew 0.3 0.4] [--skew-min-px 20 30] [--small-skew-score 0 0.5]
        [--reread-min-px 2.0] [--limit N] [--json PATH]

Runs the detector once per frame (one thread) with the refiner's threshold at the lowest of
``--thresholds``, no out-of-frame check (``DecodeConfig.max_outside_px`` None) and, where the
zoom stage's corners are checked for squareness, no squareness check; then keeps, for each
(threshold, margin, squareness setting), the gates scoring at least the threshold, square
enough (``refine.keep_square``) and with their corners within the margin of the image
(``decode.in_frame``). That equals running the detector at that setting: a gate's score and the
overlap test (greedy by score) do not depend on gates scoring less, and the squareness and the
margin are checked last, in that order. The squareness settings (``max_skew``, ``skew_min_px``,
``small_skew_score``) default to the checkpoint's. Prints, per setting and dataset,
precision, recall, PCK@2px and PCK@5px (the eval-detector rule, gates >= 20 px) and the
smallest of precision, recall and PCK@5px over all datasets (the figures #4 sets targets for),
best first; the checkpoint's own setting is marked (and always evaluated). Then the most precise
setting (the highest smallest precision over the datasets) of those whose smallest figure is at
least the checkpoint's: where one figure (PCK@5px) sets the smallest everywhere, the others can
still be chosen for. ``--reread-min-px`` (one value per run: it
changes what the refiner reads) sets ``RefineConfig.reread_min_px`` for the whole run. The split defaults to val, so that the
choice leaves the test splits for the README's figures.
"""

from __future__ import annotations

import argparse
import itertools
import sys
from dataclasses import replace
from pathlib import Path

from icarus_vision.fileio import atomic_write_json
from icarus_vision.gate_detect.cnn import CnnDetector
from icarus_vision.gate_detect.cnn.checkpoint import (
    SHIPPED,
    int8_weight_bits,
    load_checkpoint,
    load_int8,
    load_refiner,
    load_rescorer,
    load_zoom,
)
from icarus_vision.gate_detect.cnn.data import load_split, read_rgb
from icarus_vision.gate_detect.cnn.decode import in_frame
from icarus_vision.gate_detect.cnn.refine import RefineConfig, keep_square
from icarus_vision.gate_detect.evaluate import one_thread
from icarus_vision.gate_detect.metrics import evaluate_image, summarize

ROOT = Path(__file__).resolve().parents[1]
DATA = [ROOT / "datasets" / "gates-v2-ft12", ROOT / "datasets" / "gates-v2-test5"]
MIN_GATE_PX = 20.0
SETTING = ("threshold", "max_outside_px", "max_skew", "skew_min_px", "small_skew_score")
"""What a row of the sweep varies, in order."""


def loose_detector(
    path: Path, floor: float, backend: str, reread_min_px: float | None = None
) -> tuple[CnnDetector, dict, RefineConfig | None]:
    """The checkpoint's detector with its refiner's threshold at ``floor``, no out-of-frame
    check and, where it checks the zoom stage's corners for squareness, no such check (and
    ``reread_min_px`` if given); the checkpoint's own setting (``threshold``,
    ``max_outside_px``, ``max_skew``, ``skew_min_px``, ``small_skew_score``: :data:`SETTING`);
    and the refiner configuration to check squareness with afterwards (None: the detector checks
    it itself, on the refiner's corners, so it cannot be varied)."""
    model, decode_cfg, meta = load_checkpoint(path)
    refiner = load_refiner(path, meta)
    if refiner is None:
        sys.exit(f"{path}: not a detector with a refiner")
    own_cfg = refiner.cfg
    rescorer = load_rescorer(path, meta)
    threshold = own_cfg.threshold if rescorer is None else rescorer.cfg.threshold
    own = {"threshold": threshold, "max_outside_px": decode_cfg.max_outside_px,
           "max_skew": own_cfg.max_skew, "skew_min_px": own_cfg.skew_min_px,
           "small_skew_score": own_cfg.small_skew_score}  # fmt: skip
    zoom = load_zoom(path, meta)
    late = zoom is not None and own_cfg.max_skew > 0
    loose = {"threshold": floor, "max_skew": 0.0 if late else own_cfg.max_skew}
    if reread_min_px is not None:
        loose["reread_min_px"] = reread_min_px
    if rescorer is not None:  # its threshold is the one varied; the refiner's is not used
        rescorer.cfg = replace(rescorer.cfg, threshold=floor)
        loose.pop("threshold")
    refiner.cfg = replace(own_cfg, **loose)
    det = CnnDetector(
        model, replace(decode_cfg, max_outside_px=None), refiner=refiner, zoom=zoom,
        int8=load_int8(path, meta), int8_weight_bits=int8_weight_bits(meta), backend=backend,
        rescorer=rescorer,
    )  # fmt: skip
    return det, own, own_cfg if late else None


def detections(det: CnnDetector, data: Path, split: str, limit: int | None) -> list[tuple]:
    """Per image of the split: (found ``(corners, scores, score)`` list, truth, image size)."""
    d = load_split(data, split, None, limit)
    out = []
    with one_thread():
        for path, gates in zip(d.files, d.gates, strict=True):
            found = [(g.corners, g.corner_scores, g.score) for g in det.detect(read_rgb(path))]
            truth = [(g.corners, g.visibility, g.distance) for g in gates]
            out.append((found, truth, d.image_size))
    return out


def figures(
    per_image: list[tuple],
    threshold: float,
    outside: float | None,
    square: RefineConfig | None = None,
) -> dict:
    """Precision, recall and PCKs of the gates kept at ``threshold``, squareness setting
    ``square`` (None: no check here) and margin ``outside``."""
    gts, preds = [], []
    for found, truth, size in per_image:
        kept = [f for f in found if f[2] >= threshold]
        if square is not None:
            kept = keep_square(kept, size, square)
        kept = in_frame(kept, size, outside)
        g, p = evaluate_image([(c, s) for c, _, s in kept], truth, MIN_GATE_PX)
        gts += g
        preds += p
    s = summarize(gts, preds, MIN_GATE_PX)
    return {"precision": s["precision"], "recall": s["recall"], "pck_2px": s["pck"]["2px"],
            "pck_5px": s["pck"]["5px"]}  # fmt: skip


def most_precise(rows: list[dict], floor: float) -> dict | None:
    """The row with the highest smallest precision over its datasets among ``rows`` whose
    ``min`` is at least ``floor`` (None: none is)."""
    ok = [r for r in rows if r["min"] >= floor]
    return max(ok, key=lambda r: min(f["precision"] or 0 for f in r["by_data"].values()),
               default=None)  # fmt: skip


def margin(text: str) -> float | None:
    """An ``--outside`` value: pixels, or ``none``."""
    return None if text.lower() == "none" else float(text)


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--detector", default="cnn", help="cnn (shipped) or cnn:PATH")
    ap.add_argument("--backend", default="auto", help="auto, int8 or onnxruntime")
    ap.add_argument("--data", type=Path, action="append", help="repeatable (default: two)")
    ap.add_argument("--split", default="val")
    ap.add_argument("--thresholds", type=float, nargs="+", default=[0.15, 0.2, 0.25, 0.3, 0.35])
    ap.add_argument(
        "--outside",
        type=margin,
        nargs="+",
        default=[None, 0.5, 1.5, 3.0],
        help="out-of-frame margins, px ('none': no check)",
    )
    ap.add_argument(
        "--max-skew",
        type=float,
        nargs="+",
        default=None,
        help="squareness limits (0: no check; default: the checkpoint's)",
    )
    ap.add_argument(
        "--skew-min-px",
        type=float,
        nargs="+",
        default=None,
        help="smallest gates checked for squareness, px (default: the checkpoint's)",
    )
    ap.add_argument(
        "--small-skew-score",
        type=float,
        nargs="+",
        default=None,
        help="smallest score of a gate under --skew-min-px failing the squareness limit "
        "(0: never checked; default: the checkpoint's)",
    )
    ap.add_argument(
        "--reread-min-px",
        type=float,
        default=None,
        help="the refiner's RefineConfig.reread_min_px for the run (default: the checkpoint's)",
    )
    ap.add_argument("--limit", type=int, default=None, help="Only the first N images of each.")
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args(argv)
    path = Path(args.detector.partition(":")[2] or SHIPPED)
    det, own, square = loose_detector(path, min(args.thresholds), args.backend, args.reread_min_px)
    skews = args.max_skew or [own["max_skew"]]
    mins = args.skew_min_px or [own["skew_min_px"]]
    smalls = args.small_skew_score or [own["small_skew_score"]]
    checkpoint = tuple(own[k] for k in SETTING)
    if square is None and (skews, mins, smalls) != tuple([v] for v in checkpoint[2:]):
        sys.exit(f"{path}: its squareness check is not the last step (no zoom stage, or no "
                 "check), so --max-skew, --skew-min-px and --small-skew-score cannot be "
                 "varied")  # fmt: skip
    data = args.data or DATA
    runs = {str(d): detections(det, d, args.split, args.limit) for d in data}
    rows = []
    settings = list(itertools.product(args.thresholds, args.outside, skews, mins, smalls))
    if min(args.thresholds) <= own["threshold"] and checkpoint not in settings:
        settings.append(checkpoint)  # the reference the choice below is measured against
    for setting in settings:
        t, o, k, m, w = setting
        sq = None if square is None else replace(square, max_skew=k, skew_min_px=m,
                                                 small_skew_score=w)  # fmt: skip
        per = {name: figures(r, t, o, sq) for name, r in runs.items()}
        low = min(min(f["precision"] or 0, f["recall"] or 0, f["pck_5px"] or 0)
                  for f in per.values())  # fmt: skip
        row = dict(zip(SETTING, setting, strict=True))
        rows.append({**row, "min": round(low, 4), "by_data": per})
    rows.sort(key=lambda r: -r["min"])
    theirs = next((r for r in rows if tuple(r[k] for k in SETTING) == checkpoint), None)
    reread = det.select_cfg.reread_min_px
    print(f"{args.detector} on {det.backend}, {args.split} splits, reread_min_px {reread}")
    for r in rows:
        mark = " (the checkpoint's)" if r is theirs else ""
        cells = " | ".join(
            "{precision:.4f} / {recall:.4f} / {pck_2px:.4f} / {pck_5px:.4f}".format(**f)
            for f in r["by_data"].values()
        )
        print(f"threshold {r['threshold']:<5} outside {str(r['max_outside_px']):<4} "
              f"skew {r['max_skew']:<4} from {r['skew_min_px']:<4} (under it, from score "
              f"{r['small_skew_score']:<4}) min {r['min']:.4f} | {cells}{mark}")  # fmt: skip
    best = most_precise(rows, theirs["min"]) if theirs else None
    if best is not None:
        print("the most precise of those at least as good as the checkpoint's: "
              + ", ".join(f"{k} {best[k]}" for k in SETTING) + f" (min {best['min']:.4f})")  # fmt: skip
    out = {"detector": args.detector, "backend": det.backend, "split": args.split,
           "reread_min_px": reread, "data": [str(d) for d in data], "own": own,
           "rows": rows, "most_precise": best}  # fmt: skip
    if args.json:
        atomic_write_json(args.json, out)
    return out


if __name__ == "__main__":
    main()
