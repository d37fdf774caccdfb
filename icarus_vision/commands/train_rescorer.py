"""`icarus-vision train-rescorer`: train the CNN detector's fourth stage on a trained detector."""

from __future__ import annotations

from pathlib import Path

import typer

from icarus_vision.cli import app, console, user_errors


@app.command("train-rescorer")
@user_errors
def train_rescorer_cmd(
    data: list[str] = typer.Option(
        ...,
        help="gen-dataset output whose images the detector reads, or a COCO-keypoints folder of "
        "labelled real images (import-gates; read as train), ideally images none of its "
        "networks was trained on; repeat to use several, each as DIR:SHARE for its share of the "
        "training draws (rows drawn by image; e.g. --data renders:7 --data real:1); with no share given, every image counts alike, whichever folder it is in.",
    ),
    out: Path = typer.Option(
        ..., help="Output folder: the detector with the rescorer added, and candidates.npz."
    ),
    detector: Path = typer.Option(
        None, help="The detector (with a refiner and zoom stage) to add it to (default: shipped)."
    ),
    splits: str = typer.Option("train", help="Splits of each --data to read, comma-separated."),
    epochs: int = typer.Option(40, min=1, help="Passes over the candidates."),
    seed: int = typer.Option(0, help="Random seed (held-out images, weights, shuffling)."),
    threshold: float = typer.Option(
        0.2, min=0.0, max=1.0, help="Smallest rescored probability of a reported gate."
    ),
    hidden: str = typer.Option("32,32", help="Units of each hidden layer, comma-separated."),
    limit: int = typer.Option(
        None, min=1, help="Use only the first N images of each split (quick runs)."
    ),
    backend: str = typer.Option(
        "auto",
        help="How the detector's networks run while reading: auto, int8, onnxruntime, torch.",
    ),
) -> None:
    """Train the rescorer: a small MLP that scores each of the detector's candidates again from
    the refiner's and first stage's scores and what the zoom stage and the squareness of the
    opening say, instead of the refiner's probability times the first stage's score.

    The detector reads every image of the splits as when detecting (a progress bar); the
    candidates are kept in OUT/candidates.npz, which a second run with the same detector and
    data reuses. While they are read, each thousand images' rows are saved in
    OUT/candidates.parts/: after Ctrl-C the same command continues from there. Writes OUT as a
    complete detector checkpoint (the detector's files plus rescore.safetensors). Use it with
    --detector cnn:OUT.
    """
    from icarus_vision.commands.train_detector import parse_data
    from icarus_vision.gate_detect.cnn.checkpoint import SHIPPED
    from icarus_vision.gate_detect.cnn.rescore import RescoreConfig
    from icarus_vision.gate_detect.cnn.rescore_train import RescoreTrainConfig, train_rescorer

    try:
        units = tuple(int(h) for h in hidden.split(","))
    except ValueError:
        raise typer.BadParameter(
            f"--hidden: integers separated by commas, got {hidden!r}"
        ) from None
    names = [s.strip() for s in splits.split(",") if s.strip()]
    if not names or not set(names) <= {"train", "val", "test"}:
        raise typer.BadParameter(f"--splits must name train, val or test, got {splits!r}")
    folder, history = train_rescorer(
        SHIPPED if detector is None else detector, parse_data(data), out, names,
        RescoreConfig(hidden=units, threshold=threshold),
        RescoreTrainConfig(epochs=epochs, seed=seed, limit=limit),
        log=lambda s: console.print(s, highlight=False), backend=backend,
    )  # fmt: skip
    best = min(history, key=lambda h: h["held_out_loss"])
    console.print(
        f"best epoch {best['epoch']}: held-out loss {best['held_out_loss']:.4f}, accuracy "
        f"{best['held_out_accuracy']:.4f}; detector written to {folder}",
        highlight=False,
    )
