"""`icarus-vision import-gates`: a public labelled gate set as a COCO-keypoints folder."""

from __future__ import annotations

from contextlib import ExitStack
from pathlib import Path

import typer
from rich.markup import escape
from rich.progress import BarColumn, MofNCompleteColumn, TextColumn, TimeElapsedColumn

from icarus_vision.cli import app, console, progress_reporter, user_errors


@app.command("import-gates")
@user_errors
def import_gates_cmd(
    src: Path = typer.Argument(
        ...,
        help="The label file (alphapilot: .json, corners-csv: .csv), the labels/ folder "
        "(yolo-pose), or a folder holding it.",
    ),
    fmt: str = typer.Option(
        ...,
        "--format",
        help="alphapilot ({image: [[x1, y1, ..., x4, y4], ...]}), corners-csv "
        "(filename,x1,y1,...,x4,y4 per gate) or yolo-pose (labels/<stem>.txt: cls cx cy w h "
        "x y v x4, normalised).",
    ),
    out: Path = typer.Option(
        ..., help="Folder to write (empty or new): images/ and annotations.json."
    ),
    images: Path = typer.Option(
        None, help="Image folder (default: images/ beside the labels, else the labels' folder)."
    ),
    unlabelled: bool = typer.Option(
        False,
        "--unlabelled/--labelled-only",
        help="Also import the images without a label entry, as images without gates.",
    ),
) -> None:
    """Convert a labelled set of real gate images into a COCO-keypoints folder that
    `eval-detector --data` reads (and `train-detector` can mix with renders).

    Each gate's four inner-opening corners are put in TL, TR, BR, BL order as seen in the image,
    whatever corner the source starts at. Images are copied, not changed.
    """
    from icarus_vision.dataset.importers import import_gates

    with ExitStack() as stack:
        cols = (TextColumn("[bold]import-gates"), BarColumn(), MofNCompleteColumn(),
                TimeElapsedColumn())  # fmt: skip
        progress = progress_reporter(stack, cols, transient=True)
        r = import_gates(fmt, src, out, images, unlabelled, progress)
    console.print(
        f"{r['images']} images ({r['images_without_gates']} without gates), {r['gates']} gates "
        f"written to {escape(r['out'])}",
        highlight=False,
    )
