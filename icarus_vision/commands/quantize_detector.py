"""`icarus-vision quantize-detector`: int8 copies of a CNN detector's networks, for faster CPUs."""

from __future__ import annotations

from contextlib import ExitStack
from pathlib import Path

import typer
from rich.markup import escape
from rich.progress import BarColumn, MofNCompleteColumn, TextColumn, TimeElapsedColumn

from icarus_vision.cli import app, console, progress_reporter, user_errors


def checkpoint_of(spec: str) -> str | None:
    """The checkpoint of a ``cnn`` / ``cnn:PATH`` detector spec (None: the shipped one)."""
    name, _, path = spec.partition(":")
    if name != "cnn" or (_ and not path):
        raise ValueError(f"--detector must be cnn or cnn:PATH, got {spec!r}")
    return path or None


@app.command("quantize-detector")
@user_errors
def quantize_detector_cmd(
    data: list[Path] = typer.Option(
        ..., help="gen-dataset output folder whose frames calibrate (repeatable)."
    ),
    out: Path = typer.Option(
        ...,
        help="Checkpoint folder to write: a copy of --detector with int8 networks added "
        "(the same folder: added in place).",
    ),
    detector: str = typer.Option("cnn", help="cnn (shipped) or cnn:PATH (checkpoint)."),
    images: int = typer.Option(400, min=1, help="Calibration frames, drawn at random."),
    split: str = typer.Option("val", help="Which split of --data the frames come from."),
    seed: int = typer.Option(0, help="Seed of the frames' draw."),
) -> None:
    """Add int8 copies of a CNN detector's networks (ONNX Runtime static quantization).

    The float32 detector runs on the calibration frames; what each network reads there sets the
    int8 activation ranges; weights have 7 bits, so that CPUs without 8-bit dot products sum
    them exactly. The first and output layers stay float32. `eval-detector` and `race` run the
    int8 copies on x86 CPUs with AVX2, VNNI or AMX, else float32.
    """
    from icarus_vision.gate_detect.cnn.quantize import quantize_detector

    with ExitStack() as stack:
        cols = (TextColumn("[bold]calibrating"), BarColumn(), MofNCompleteColumn(),
                TimeElapsedColumn())  # fmt: skip
        progress = progress_reporter(stack, cols, transient=True)
        record = quantize_detector(checkpoint_of(detector), data, out, images, split, seed,
                                   progress)  # fmt: skip
    nets = ", ".join(record["networks"])
    console.print(
        f"int8 {nets} calibrated on {record['calibration']['images']} {split} frames; "
        f"checkpoint written to {escape(str(out))}",
        highlight=False,
    )
