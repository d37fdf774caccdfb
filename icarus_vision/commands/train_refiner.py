"""`icarus-vision train-refiner`: train the CNN detector's second stage on a trained first stage."""

from __future__ import annotations

from pathlib import Path

import typer

from icarus_vision.cli import app, console, user_errors
from icarus_vision.commands.train_detector import print_best


@app.command("train-refiner")
@user_errors
def train_refiner_cmd(
    data: list[str] = typer.Option(
        ...,
        help="gen-dataset output (train and val splits), ideally generated with a seed the "
        "first stage was not trained on, or a COCO-keypoints folder of labelled real images at "
        "the camera's size (import-gates; training only); repeat to train on several (the first "
        "one's val split validates, unless --val), each as DIR:SHARE for its share of the "
        "training draws (e.g. --data renders:7 --data real:1); with no share given, every image counts alike, whichever folder it is in.",
    ),
    val: list[Path] = typer.Option(
        None,
        help="Datasets whose val splits, together, validate and tune (repeatable; default: the "
        "first --data). A finished run resumed with other --val is tuned again on them.",
    ),
    out: Path = typer.Option(..., help="Output folder: best/, last/, refiner.onnx, tb/."),
    detector: Path = typer.Option(
        None, help="The first stage: a detector checkpoint (default: the shipped one)."
    ),
    epochs: int = typer.Option(12, min=1, help="Total epochs (a resumed run continues to this)."),
    seed: int = typer.Option(0, help="Random seed (weights, shuffling, augmentation)."),
    resume: bool = typer.Option(
        False, "--resume", help="Continue the run in OUT/last with its own settings."
    ),
    patch: int = typer.Option(
        48, min=16, help="Side of a new refiner's patch, px (a multiple of 8)."
    ),
    margin: int = typer.Option(
        8,
        min=1,
        help="Patch pixels between a new refiner's opening and the patch border on each side "
        "(the context it sees around the opening; less than half the patch).",
    ),
    widths: str = typer.Option(
        "16,32,64", help="Channels of a new refiner's three stages, comma-separated."
    ),
    hidden: int = typer.Option(64, min=1, help="Units of a new refiner's hidden layer."),
    square_hfov: float = typer.Option(
        0.0,
        min=0.0,
        max=170.0,
        help="Also tell a new refiner how square each candidate is in 3-D under a camera of "
        "this horizontal field of view, degrees (0: not told).",
    ),
    candidate_scale: float = typer.Option(
        1.0,
        min=0.1,
        max=1.0,
        help="A new run's training candidates: the corner network reads their frames at this "
        "fraction of the camera's size (0.8: 256x192, as the shipped detector reads them).",
    ),
    init: Path = typer.Option(
        None,
        help="Start a new run from this checkpoint's refiner (its architecture: --patch, "
        "--margin, --widths, --hidden and --square-hfov are then not used), e.g. to fine-tune it on new "
        "data with a lower --lr.",
    ),
    lr: float = typer.Option(2e-3, min=0.0, help="Peak learning rate of a new run (AdamW)."),
    candidate_iou: float = typer.Option(
        0.5,
        min=0.01,
        max=1.0,
        help="A new run's training candidates overlapping a better one by more than this are "
        "dropped (0.85: as the shipped detector does).",
    ),
    images_on_disk: bool = typer.Option(
        False,
        "--images-on-disk",
        help="Keep a new run's training images in OUT/train-images.npy, mapped from disk, "
        "instead of in memory (230 kB an image: for more images than memory holds).",
    ),
) -> None:
    """Train the refiner: it rectifies each of the first stage's candidate gates into a small
    patch, decides whether it is a gate and corrects its corners.

    Writes OUT/best and OUT/last (complete detector checkpoints: the first stage with its
    candidate decoding, plus refiner.safetensors), OUT/refiner.onnx, OUT/history.json and
    TensorBoard logs in OUT/tb. Ctrl-C saves OUT/last; --resume continues from it. At the end,
    OUT/best is tuned on val: the gate threshold, snap radius, squareness check, mirrored
    reading, number of passes and the corner network's input size (--resume on a finished run
    only tunes again). Use the result with --detector cnn:OUT/best.
    """
    from icarus_vision.commands.train_detector import parse_data, parse_widths
    from icarus_vision.gate_detect.cnn.checkpoint import SHIPPED
    from icarus_vision.gate_detect.cnn.refine import RefineConfig
    from icarus_vision.gate_detect.cnn.refine_train import RefineTrainConfig, train_refiner

    if not margin < patch // 2:
        raise typer.BadParameter(
            f"must be less than half the patch ({patch} px)", param_hint="--margin"
        )
    result = train_refiner(
        SHIPPED if detector is None else detector, parse_data(data), out, epochs=epochs, seed=seed,
        resume=resume,
        config=RefineTrainConfig(candidate_scale=candidate_scale, candidate_iou=candidate_iou,
                                 lr=lr,
                                 images_on_disk=images_on_disk),
        refine_config=RefineConfig(
            patch=patch, margin=margin, widths=parse_widths(widths, 3), hidden=hidden,
            square_hfov_deg=square_hfov,
        ),
        log=lambda s: console.print(s, highlight=False), val_data=val or None, init=init,
    )  # fmt: skip
    print_best(result.best_epoch, result.best_metrics, out, "best/, last/, refiner.onnx")
