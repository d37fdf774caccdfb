"""`icarus-vision build-detector`: datasets, every stage, tuning and int8 copies in one command."""

from __future__ import annotations

from pathlib import Path

import typer
from rich.markup import escape

from icarus_vision.cli import app, console, stop_on_sigterm, user_errors


@app.command("build-detector")
@user_errors
def build_detector_cmd(
    config: Path = typer.Option(
        Path("configs/detector-build.toml"),
        help="Build file: datasets to render and stages to train (configs/detector-build.toml "
        "rebuilds the shipped detector).",
    ),
    out: Path = typer.Option(..., help="Build folder: datasets/, one folder per stage, detector/."),
    scale: float = typer.Option(
        1.0, help="Multiply every dataset's images and stage's epochs (e.g. 0.05: a quick run)."
    ),
    workers: int = typer.Option(2, min=1, help="Rendering processes for the datasets."),
    seed: int = typer.Option(0, help="Seed of every stage's training."),
) -> None:
    """Build a CNN detector from nothing: render the build file's datasets, train the corner
    network, refiner, zoom stage and rescorer one on the other (each tunes its thresholds on
    val), add int8 copies and evaluate it, with no hand edits.

    Resumable: run the same command again after Ctrl-C, SIGTERM or a crash; finished steps are
    skipped and an interrupted stage continues from its last epoch. OUT/build.json records each
    step's time over every run that worked on it; OUT/detector is the finished checkpoint
    (--detector cnn:OUT/detector; copy its files into icarus_vision/models/detector/ to ship it).
    """
    from icarus_vision.gate_detect.cnn.build import build_detector, load_build

    spec = load_build(config)
    stop_on_sigterm()
    final = build_detector(spec, out, scale=scale, workers=workers, seed=seed,
                           log=lambda s: console.print(s, highlight=False))  # fmt: skip
    console.print(f"detector written to {escape(str(final))}", highlight=False)
