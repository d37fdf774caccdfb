"""`icarus-vision train-zoom`: train the CNN detector's third stage on a trained detector."""

from __future__ import annotations

from pathlib import Path

import typer

from icarus_vision.cli import app, console, user_errors
from icarus_vision.commands.train_detector import print_best


@app.command("train-zoom")
@user_errors
def train_zoom_cmd(
    data: list[str] = typer.Option(
        ...,
        help="gen-dataset output whose train split is trained on, or a COCO-keypoints folder of "
        "labelled real images (import-gates), ideally images the detector was not trained on; "
        "repeat to train on several, each as DIR:SHARE for its share of the training draws "
        "(e.g. --data renders:7 --data real:1); with no share given, every image counts alike, whichever folder it is in.",
    ),
    out: Path = typer.Option(..., help="Output folder: best/, last/, zoom.onnx, tb/."),
    val: Path = typer.Option(
        None, help="The dataset whose val split validates and tunes (default: the first --data)."
    ),
    detector: Path = typer.Option(
        None, help="The detector (with a refiner) to add the stage to (default: the shipped one)."
    ),
    epochs: int = typer.Option(6, min=1, help="Total epochs (a resumed run continues to this)."),
    seed: int = typer.Option(0, help="Random seed (jitter, weights, shuffling, augmentation)."),
    resume: bool = typer.Option(
        False, "--resume", help="Continue the run in OUT/last with its own settings."
    ),
    limit: int = typer.Option(
        None, min=1, help="Use only the first N images of each split (quick runs)."
    ),
    patch: int = typer.Option(
        32, min=8, help="Side of a new stage's patches, px (a multiple of 8)."
    ),
    widths: str = typer.Option(
        "16,32,48,64", help="Channels of a new stage at full, half, quarter and eighth resolution."
    ),
    hidden: int = typer.Option(128, min=1, help="Units of a new stage's hidden layer."),
    extent: float = typer.Option(
        0.25,
        min=0.05,
        max=1.0,
        help="A patch spans this fraction of the gate's side on each side of the corner.",
    ),
    copies: int = typer.Option(
        2, min=0, help="Copies of each detection with its corners moved at random (--jitter)."
    ),
    jitter: float = typer.Option(
        0.02, min=0.0, help="Standard deviation of the copies' corner noise, fraction of the side."
    ),
    wide_copies: int = typer.Option(
        0, min=0, help="Copies more, each with one corner moved by --wide-jitter instead."
    ),
    wide_jitter: float = typer.Option(
        0.15, min=0.0, help="Standard deviation of that corner's noise, fraction of the side."
    ),
) -> None:
    """Train the zoom stage: it reads each corner of every gate the detector reports (at least
    20-60 px across, tuned) again in a patch zoomed in on that corner, and moves the corner.

    Writes OUT/best and OUT/last (complete detector checkpoints: the detector's networks plus
    zoom.safetensors), OUT/examples.npz (the training patches, cut once), OUT/zoom.onnx,
    OUT/history.json and TensorBoard logs in OUT/tb. Ctrl-C saves OUT/last; --resume continues
    from it. At the end, the smallest gate the stage reads is tuned on val. Use the result with
    --detector cnn:OUT/best.
    """
    from icarus_vision.commands.train_detector import parse_data, parse_widths
    from icarus_vision.gate_detect.cnn.checkpoint import SHIPPED
    from icarus_vision.gate_detect.cnn.zoom import ZoomConfig
    from icarus_vision.gate_detect.cnn.zoom_train import ZoomTrainConfig, train_zoom

    result = train_zoom(
        SHIPPED if detector is None else detector, parse_data(data), out, val_dir=val,
        epochs=epochs, seed=seed, resume=resume, config=ZoomTrainConfig(limit=limit, copies=copies, jitter=jitter,
                               wide_copies=wide_copies, wide_jitter=wide_jitter),
        zoom_config=ZoomConfig(
            patch=patch, extent=extent, widths=parse_widths(widths, 4), hidden=hidden
        ),
        log=lambda s: console.print(s, highlight=False),
    )  # fmt: skip
    print_best(result.best_epoch, result.best_metrics, out, "best/, last/, zoom.onnx")
