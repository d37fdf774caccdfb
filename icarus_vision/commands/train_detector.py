"""`icarus-vision train-detector`: train the CNN gate-corner detector on gen-dataset folders (and
labelled real images), mixed by share."""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import typer
from rich.markup import escape

from icarus_vision.cli import app, console, user_errors


@app.command("train-detector")
@user_errors
def train_detector_cmd(
    data: list[str] = typer.Option(
        ...,
        help="gen-dataset output folder (train and val splits), or a COCO-keypoints folder of "
        "labelled real images (import-gates; training only); repeat to mix several, each as "
        "DIR:SHARE for its share of the training draws (e.g. --data renders:7 --data real:1); "
        "several folders without shares each get an equal share of the draws.",
    ),
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
    widths: str | None = typer.Option(
        None,
        help="Channels of the four encoder stages of a new network, comma-separated "
        "(default: 16,32,64,160).",
    ),
    head_width: int | None = typer.Option(
        None, min=1, help="Channels of a new network's decoder head (default: 32)."
    ),
    ema_decay: float = typer.Option(
        0.0,
        help="Validate and keep as best an exponential moving average of the weights, updated "
        "every step with this decay, e.g. 0.999 (0: off).",
    ),
    init: Path | None = typer.Option(
        None,
        help="Start from this detector checkpoint's corner network (its architecture and "
        "weights) instead of random weights: fine-tuning.",
    ),
    input_size: str | None = typer.Option(
        None,
        help="Frames are resized to this for the network, WxH (default: the camera's, 320x240).",
    ),
    lr: float = typer.Option(3e-3, min=0.0, help="Peak learning rate (lower to fine-tune)."),
) -> None:
    """Train the corner network with augmentation; validate every epoch.

    Writes OUT/best and OUT/last (model.safetensors + detector.json), OUT/model.onnx (best
    weights), OUT/history.json and TensorBoard logs in OUT/tb. Ctrl-C saves OUT/last; --resume
    continues from it (with the run's own settings and network). Use the result with
    --detector cnn:OUT/best.
    """
    from icarus_vision.gate_detect.cnn.model import ModelConfig
    from icarus_vision.gate_detect.cnn.train import TrainConfig, train_detector

    if init is not None and (widths is not None or head_width is not None):
        raise ValueError("--init takes the checkpoint's network: drop --widths/--head-width")
    model = ModelConfig()
    if widths is not None:
        model = replace(model, widths=parse_widths(widths))
    if head_width is not None:
        model = replace(model, head_width=head_width)
    if input_size is not None:
        model = replace(model, input_size=parse_size(input_size))
    result = train_detector(
        parse_data(data), out, epochs=epochs, seed=seed, resume=resume, model_config=model, init=init,
        config=TrainConfig(ignore_below_px=ignore_below_px, ema_decay=ema_decay, lr=lr),
        log=lambda s: console.print(s),
    )  # fmt: skip
    print_best(result.best_epoch, result.best_metrics, out, "best/, last/, model.onnx")


def print_best(epoch: int, m: dict, out: Path, files: str) -> None:
    """The closing lines of a training command: the best epoch's figures and what was written."""
    console.print(
        f"best epoch {epoch}: precision {m.get('precision')}, recall "
        f"{m.get('recall')}, median corner error {m.get('corner_error_px', {}).get('median')} px",
        highlight=False,
    )
    console.print(f"checkpoints written to {escape(str(out))}/ ({files})")


def parse_data(values: list[str]) -> list[Path | tuple[Path, float]]:
    """``--data DIR[:SHARE]`` (repeatable, every training command) -> each folder, as a path or,
    where a share is given, (folder, share); a folder whose name ends in ``:`` and a number is
    read as DIR:SHARE.

    Raises:
        ValueError: a share that is not a number > 0 (``DIR:x``, ``DIR:0``, ``DIR:-1``).
    """
    from icarus_vision.dataset.layout import split_share

    out = []
    for v in values:
        head, share = split_share(v)
        unread = share is None and ":" in v and not Path(v).exists()
        if unread or (share is not None and not 0 < share < math.inf):
            raise ValueError(f"--data {v}: the share after ':' must be a number > 0")
        out.append(Path(head) if share is None else (Path(head), share))
    return out


def parse_widths(text: str, n: int = 4) -> tuple[int, ...]:
    """``--widths``: ``n`` positive channel counts, comma-separated."""
    try:
        w = tuple(int(v) for v in text.split(","))
    except ValueError:
        w = ()
    if len(w) != n or min(w) < 1:
        example = ",".join(str(16 * 2**i) for i in range(n))
        raise ValueError(f"--widths: expected {n} positive integers like {example}, got {text!r}")
    return w


def parse_size(text: str) -> tuple[int, int]:
    """``--input-size``: ``WxH``, two positive integers divisible by 4."""
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        w = h = 0
    if w < 4 or h < 4 or w % 4 or h % 4:
        raise ValueError(f"--input-size: expected WxH, multiples of 4, like 256x192, got {text!r}")
    return w, h
