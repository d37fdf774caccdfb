"""The detector on real photographs of real gates: precision, recall and corner error.

    .venv/bin/python benchmarks/real_gates.py [--detector cnn] [--sets ../shared/real-gates]
        [--min-gate-px 20] [--backend auto] [--min-score S [S ...]] [--json PATH]

Reads the measurement-only sets of ``../shared/real-gates/`` (never trained on, never copied into
the project): ``alphapilot/`` (11 AIRR photos, 1296x864, AlphaPilot's label JSON) and
``cyberzoo/`` (494 low-resolution fisheye frames, 315x160, a corners CSV; the 248 without a gate
count false positives). Each is converted by ``import-gates`` into a temporary folder outside the
project and scored by ``eval-detector``'s rule (gates with a mean side of at least
``--min-gate-px``); the corner error is also given as a fraction of the gate's mean side. A set
that is not there is skipped (the script says so). With ``--min-score``, only gates the CNN
scores at least that count; several values print the precision-recall trade-off.
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

from icarus_vision.dataset.importers import import_gates
from icarus_vision.fileio import atomic_write_json
from icarus_vision.gate_detect.evaluate import eval_detector

SETS = {
    "alphapilot": ("alphapilot", "alphapilot/labels.json", False),
    "cyberzoo": ("corners-csv", "cyberzoo/corners.csv", True),
}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--detector", default="cnn")
    ap.add_argument(
        "--sets", default=str(Path(__file__).resolve().parents[2] / "shared" / "real-gates")
    )
    ap.add_argument("--min-gate-px", type=float, default=20.0)
    ap.add_argument(
        "--backend", default=None,
        help="what runs a CNN's networks: auto (default), int8, onnxruntime or torch",
    )  # fmt: skip
    ap.add_argument(
        "--min-score", type=float, nargs="+", default=None,
        help="cnn only: count only gates scored at least this; several values give the "
        "precision-recall trade-off (one row per value)",
    )  # fmt: skip
    ap.add_argument("--json", default=None)
    args = ap.parse_args()
    root = Path(args.sets)
    out = {
        "detector": args.detector,
        "backend": args.backend,
        "min_gate_px": args.min_gate_px,
        "sets": {},
    }
    with tempfile.TemporaryDirectory(prefix="icarus-real-") as tmp:
        for name, (fmt, labels, unlabelled) in SETS.items():
            if not (root / labels).is_file():
                print(f"{name}: {root / labels} not found, skipped")
                continue
            folder = Path(tmp) / name
            import_gates(fmt, root / labels, folder, unlabelled=unlabelled)
            rows = []
            for score in args.min_score or [None]:
                r = eval_detector(
                    folder, args.detector, min_gate_px=args.min_gate_px, resamples=0,
                    backend=args.backend, min_score=score,
                )  # fmt: skip
                row = {
                    "min_score": score, "images": r["images"], "gates": r["gates"],
                    "precision": r["precision"], "recall": r["recall"],
                    "false_positives": r["false_positives"],
                    "corner_error_median_px": r["corner_error_px"]["median"],
                    "corner_error_median_side": r["corner_error_side"]["median"],
                    "ms_per_frame": r["ms_per_frame"],
                }  # fmt: skip
                rows.append(row)
                rel = row["corner_error_median_side"]
                at = "" if score is None else f" (gates scored >= {score:g})"
                print(f"{name}{at}: {row['images']} images, {row['gates']} gates; precision "
                      f"{row['precision']}, recall {row['recall']}, median corner error "
                      f"{row['corner_error_median_px']} px = "
                      f"{'-' if rel is None else f'{100 * rel:.1f}'} % of the side")  # fmt: skip
            out["sets"][name] = rows[0] if len(rows) == 1 else rows
    if args.json:
        atomic_write_json(args.json, out)


if __name__ == "__main__":
    main()
