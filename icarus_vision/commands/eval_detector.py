"""`icarus-vision eval-detector`: detector accuracy and speed on a dataset's test (or val) split."""

from __future__ import annotations

from contextlib import ExitStack
from pathlib import Path

import typer
from rich.markup import escape
from rich.progress import BarColumn, MofNCompleteColumn, TextColumn, TimeElapsedColumn
from rich.table import Table

from icarus_vision.cli import app, console, progress_reporter, user_errors
from icarus_vision.dataset.layout import SPLITS


def _fmt(x) -> str:
    return "-" if x is None else f"{x:.3f}" if isinstance(x, float) else str(x)


def _span(b: dict) -> str:
    if b["min"] == "all":
        return "all"
    return f"{b['min']:g}-" + ("" if b["max"] is None else f"{b['max']:g}")


def _table(title: str, first: str, rows: list[dict]) -> Table:
    table = Table(title=title)
    for col in (first, "gates", "false pos.", "precision", "recall", "median px", "% of side",
                "PCK@2", "PCK@5"):  # fmt: skip
        table.add_column(col, justify="right")
    for b in rows:
        rel = b["corner_error_side"]["median"]
        table.add_row(_span(b), str(b["gates"]), str(b["false_positives"]), _fmt(b["precision"]),
                      _fmt(b["recall"]), _fmt(b["corner_error_px"]["median"]),
                      "-" if rel is None else f"{100 * rel:.1f}", _fmt(b["pck"]["2px"]),
                      _fmt(b["pck"]["5px"]))  # fmt: skip
    return table


@app.command("eval-detector")
@user_errors
def eval_detector_cmd(
    data: Path = typer.Option(
        ...,
        help="gen-dataset output folder (its --split is used), a COCO-keypoints folder (one "
        "annotation file and images/, e.g. from import-gates: real images), or a folder of "
        "images without gates (counts false positives).",
    ),
    detector: str = typer.Option("cnn", help="cnn (shipped), cnn:PATH (checkpoint) or opencv."),
    json_path: Path = typer.Option(None, "--json", help="Write the report to this JSON file."),
    error_model: Path = typer.Option(
        None, help="Write the error model here (default: beside --json, .error_model.json)."
    ),
    min_gate_px: float = typer.Option(20.0, help="Smallest counted gate (mean side), pixels."),
    limit: int = typer.Option(None, min=1, help="Evaluate only the first N images of the split."),
    examples: Path = typer.Option(
        None, help="Also draw images of the split with true and found gates (.jpg/.png)."
    ),
    num_examples: int = typer.Option(12, min=1, help="How many images --examples draws."),
    resamples: int = typer.Option(
        1000, min=0, help="Bootstrap resamples of the images for 95 % intervals (0: none)."
    ),
    seed: int = typer.Option(0, help="Seed of the bootstrap."),
    split: str = typer.Option(
        "test", help="Which split: test, or val to compare detectors without reading test."
    ),
    backend: str = typer.Option(
        None, help="cnn only: what runs its networks: auto (default), int8, onnxruntime or torch."
    ),
    min_score: float = typer.Option(
        None,
        min=0.0,
        max=1.0,
        help="cnn only: count only gates scored at least this (a confidence threshold: fewer "
        "false gates for fewer found; default: all the detector reports).",
    ),
) -> None:
    """Precision, recall, corner error (pixels and % of the gate's side), PCK and ms/frame (one
    core), overall and by distance/size, with 95 % confidence intervals (bootstrap over the
    images), on a dataset's test split (or --split val), on real labelled images (a COCO folder:
    by size only), or on images without gates.

    Images of any size and aspect are read whole (letterboxed to the network's input, not
    stretched). Also writes the detector's error model (gate-centre error and miss rate by
    distance) for `train-policy`'s perception noise, where the data has distances.
    """
    from icarus_vision.fileio import check_output
    from icarus_vision.gate_detect.evaluate import eval_detector

    if split not in SPLITS:
        raise typer.BadParameter(f"expected one of {', '.join(SPLITS)}", param_hint="--split")
    check_output(json_path)
    with ExitStack() as stack:
        cols = (TextColumn("[bold]eval-detector"), BarColumn(), MofNCompleteColumn(),
                TimeElapsedColumn())  # fmt: skip
        progress = progress_reporter(stack, cols, transient=True)
        r = eval_detector(data, detector, json_path, error_model, min_gate_px, split, limit=limit,
                          progress=progress, examples_path=examples,
                          examples=num_examples, seed=seed, resamples=resamples,
                          backend=backend, min_score=min_score)  # fmt: skip
    split_name = f"{r['split']} " if r["has_distance"] else ""
    title = (f"{r['detector']} on {r['images']} {split_name}images, {r['gates']} gates >= "
             f"{r['min_gate_px']:g} px")  # fmt: skip
    rows = [{"min": "all", "max": None, **r}, *(r["by_distance"] if r["has_distance"] else [])]
    console.print(_table(title, "distance m" if r["has_distance"] else "", rows))
    # the report has every size; below min_gate_px no false positive is counted (the rule)
    sizes = [b for b in r["by_size"] if b["max"] is None or b["max"] > r["min_gate_px"]]
    console.print(_table("by apparent size (mean side of the opening)", "size px", sizes))
    ci = r["confidence"]
    if ci:
        names = {"precision": "precision", "recall": "recall", "corner_error_median_px":
                 "median px", "pck_2px": "PCK@2", "pck_5px": "PCK@5"}  # fmt: skip
        spans = ", ".join(f"{v} {ci[k][0]:.3f}-{ci[k][1]:.3f}" for k, v in names.items() if ci[k])
        console.print(f"95 % intervals (bootstrap over images): {spans}", highlight=False)
    backend = f", {r['backend']}" if r["backend"] else ""
    if r["min_score"] is not None:
        backend += f", gates scored >= {r['min_score']:g}"
    console.print(f"{r['ms_per_frame']:.2f} ms per frame (one core{backend}; {r['cpu']})",
                  highlight=False)  # fmt: skip
    if r["error_model_path"]:
        console.print(f"error model written to {escape(r['error_model_path'])}", highlight=False)
    if r["examples_path"]:
        console.print(f"examples drawn in {escape(r['examples_path'])}", highlight=False)
    if json_path is not None:
        console.print(f"report written to {escape(str(json_path))}", highlight=False)
