"""`icarus-vision train-detector`: train the CNN gate-corner detector on a gen-dataset folder."""

from __future__ import annotations

from pathlib import Path

import typer
from rich.markup import escape

from icarus_vision.cli import app, console, user_errors


@app.command("train-detector")
@user_errors
def train_detector_cmd(
    data: Path = typer.Option(..., help="gen-dataset output folder (train and val splits)."),
    out: Path = typer.Option(..., help="Output folder: best/, last/, model.onnx, tb/."),
    epochs: int = typer.Option(12, min=1, help="Total epochs (a resumed run continues to this)."),
    seed: int = typer.Option(0, help="Random seed (weights, shuffling, augmentation)."),
    resume: bool = typer.Option(
        False, "--resume", help="Continue the run in OUT/last with its own settings."
    ),
    ignore_below_px: float = typer.Option(
        0.0,
        min=0.0,
        help="Gates smaller than this (mean side of the opening, px) are not training targets "
        "and a detection near one is not penalised (0: all gates are targets).",
    ),
) -> None:
    """Train the corner network with augmentation; validate every epoch.

    Writes OUT/best and OUT/last (model.safetensors + detector.json), OUT/model.onnx (best
    weights), OUT/history.json and TensorBoard logs in OUT/tb. Ctrl-C saves OUT/last; --resume
    continues from it. Use the result with --detector cnn:OUT/best.
    """
    from icarus_vision.gate_detect.cnn.train import TrainConfig, train_detector

    result = train_detector(
        data, out, epochs=epochs, seed=seed, resume=resume,
        config=TrainConfig(ignore_below_px=ignore_below_px), log=lambda s: console.print(s),
    )  # fmt: skip
    m = result.best_metrics
    console.print(
        f"best epoch {result.best_epoch}: precision {m.get('precision')}, recall "
        f"{m.get('recall')}, median corner error {m.get('corner_error_px', {}).get('median')} px",
        highlight=False,
    )
    console.print(f"checkpoints written to {escape(str(out))}/ (best/, last/, model.onnx)")
