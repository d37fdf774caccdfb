"""``train_detector``: train the corner network on a gen-dataset folder.

Output folder layout::

    OUT/best/    model.safetensors + detector.json  (best validation score; at the end its
                 decoding thresholds are tuned on the val split)
    OUT/last/    the same, plus train_state.pt (optimizer, schedule, epoch and the weights'
                 moving average, if any: what --resume reads)
    OUT/model.onnx   ONNX export of the best weights
    OUT/history.json per-epoch losses and validation metrics
    OUT/tb/      TensorBoard logs

Every file is written atomically. Ctrl-C saves ``last/`` (the interrupted epoch is redone on
resume) and re-raises ``KeyboardInterrupt``. Each epoch's shuffle and augmentation are seeded by
(seed, epoch) alone, so a resumed run trains on the same samples as one never interrupted.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, fields, replace
from pathlib import Path

import numpy as np
import torch
from torch.utils.data import DataLoader, WeightedRandomSampler

from icarus_vision.fileio import atomic_path, atomic_write_json
from icarus_vision.gate_detect.cnn.checkpoint import export_onnx, load_checkpoint, save_checkpoint
from icarus_vision.gate_detect.cnn.data import GateDataset, load_splits
from icarus_vision.gate_detect.cnn.decode import DecodeConfig
from icarus_vision.gate_detect.cnn.model import CornerNet, ModelConfig
from icarus_vision.gate_detect.cnn.targets import detection_loss
from icarus_vision.gate_detect.cnn.tune import score as _score
from icarus_vision.gate_detect.cnn.tune import tune_decode, validate

STATE = "train_state.pt"


@dataclass(frozen=True)
class TrainConfig:
    """Settings of one training run (recorded in ``detector.json``)."""

    epochs: int = 30
    """Passes over the training split."""
    seed: int = 0
    """Seed of the initial weights, the shuffling and the augmentation."""
    batch_size: int = 32
    """Images per optimisation step."""
    lr: float = 3e-3
    """Peak learning rate of AdamW (linear warm-up, then cosine decay to 0 at the last epoch)."""
    weight_decay: float = 1e-4
    """AdamW weight decay."""
    limit: int | None = None
    """Use only the first ``limit`` images of each split (quick runs and tests)."""
    min_gate_px: float = 20.0
    """Smallest gate counted in the validation metrics, pixels."""
    ignore_below_px: float = 0.0
    """Gates whose opening's mean side is shorter than this (pixels) are no training targets, and
    a peak near one is not penalised (0: every gate is a target)."""
    tune_decode: bool = True
    """After training, choose the best weights' decoding thresholds on the val split."""
    bf16: bool | None = None
    """Run the forward pass under bfloat16 autocast (about 2x faster on CPUs with AVX512-BF16,
    about 5x slower on those without); the loss, the weights and inference stay float32. None:
    where the CPU has bfloat16 arithmetic (recorded as chosen)."""
    ema_decay: float = 0.0
    """Keep an exponential moving average of the weights (and batch-norm statistics), updated
    after every step with this decay; it is what is validated and saved as ``best`` (0: off, the
    trained weights themselves)."""


@dataclass(frozen=True)
class TrainResult:
    """What :func:`train_detector` produced: the folder, the epochs run and the best metrics."""

    out_dir: Path
    epochs_done: int
    best_epoch: int
    best_metrics: dict
    history: list[dict]


def train_detector(
    data_dir: str | Path | list,
    out_dir: str | Path,
    epochs: int = 30,
    seed: int = 0,
    resume: bool = False,
    config: TrainConfig | None = None,
    model_config: ModelConfig | None = None,
    progress: bool = True,
    log: Callable[[str], None] | None = None,
    init: str | Path | None = None,
) -> TrainResult:
    """Train (or resume training) the corner network.

    Args:
        data_dir: gen-dataset output (its ``train`` and ``val`` splits are used), or a list of
            such folders and COCO-keypoints folders (real images, ``import-gates``: training
            only), each a path or (path, share): each dataset's share of the training draws
            (images drawn with replacement by share / its images; default: all images alike).
            Validation reads the gen-dataset folders' ``val`` splits.
        out_dir: output folder (layout in the module docstring).
        epochs: total epochs (a resumed run continues up to this number).
        seed: seed of weights, shuffling and augmentation.
        resume: continue from ``OUT/last`` with the run's own settings (only ``epochs`` may
            change); without it an existing ``OUT/last`` is an error.
        config: further settings of a new run (``epochs`` and ``seed`` above take precedence).
        model_config: architecture of a new network.
        progress: show a rich progress bar.
        log: called with one line per epoch.
        init: start a new run from this checkpoint's weights (folder or file) instead of random
            ones: its architecture, with ``model_config``'s ``input_size`` (the network is
            convolutional: fine-tuning it to read frames at another size).

    Raises:
        FileNotFoundError / ValueError: bad dataset, or OUT/last present without ``resume`` (or
            missing with it).
    """
    from icarus_vision.gate_detect.cnn import native_bf16

    cfg = replace(config or TrainConfig(), epochs=epochs, seed=seed)
    if cfg.epochs < 1:
        raise ValueError(f"epochs must be >= 1, got {cfg.epochs}")
    if cfg.bf16 is None:
        cfg = replace(cfg, bf16=native_bf16())
    out = Path(out_dir)
    last_dir, best_dir = run_folders(out, resume, STATE)
    torch.manual_seed(cfg.seed)
    mcfg = model_config or ModelConfig()
    start_from = None
    if init is not None and not resume:
        start_from, _, _ = load_checkpoint(init)
        mcfg = replace(start_from.cfg, input_size=mcfg.input_size)
    model = CornerNet(mcfg)
    if start_from is not None:
        model.load_state_dict(start_from.state_dict())
    if resume:
        model, _, meta = load_checkpoint(last_dir)
        mcfg = model.cfg
        stored = meta.get("training", {}).get("config", {})
        known = {f.name for f in fields(TrainConfig)}
        cfg = replace(TrainConfig(**{k: v for k, v in stored.items() if k in known}), epochs=epochs)
    sources = data_sources(data_dir)
    dirs, shares = [d for d, _ in sources], [w for _, w in sources]
    mixed = len(sources) > 1 or any(w != 1.0 for w in shares)
    train = load_splits(dirs, "train", mcfg.input_size, cfg.limit, shares=shares if mixed else None,
                        same_size=False)  # fmt: skip
    val = load_splits(dirs, "val", mcfg.input_size, cfg.limit, same_size=False)
    grid = mcfg.grid
    decode_cfg = DecodeConfig()
    opt = torch.optim.AdamW(model.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
    steps_per_epoch = int(np.ceil(len(train.files) / cfg.batch_size))
    total = cfg.epochs * steps_per_epoch
    sched = warmup_cosine(opt, total, warmup=max(1, min(200, total // 10)))
    ema = _moving_average(model, cfg.ema_decay)
    start, history, best = 0, [], (-1.0, -1, {})
    if resume:
        start, history, best, st = load_state(last_dir / STATE, opt, sched)
        if ema is not None:
            ema.load_state_dict(st["ema"])
    gen = torch.Generator()
    ds = GateDataset(train, grid, augment=True, seed=cfg.seed, ignore_below_px=cfg.ignore_below_px)
    if train.weights is None:
        loader = DataLoader(ds, cfg.batch_size, shuffle=True, generator=gen, drop_last=False)
    else:  # each dataset its share of the draws
        sampler = WeightedRandomSampler(train.weights.tolist(), len(train.files), generator=gen)
        loader = DataLoader(ds, cfg.batch_size, sampler=sampler, drop_last=False)
    from torch.utils.tensorboard import SummaryWriter

    writer = SummaryWriter(str(out / "tb"))
    info = {"data": str(dirs[0]) if not mixed else [[str(d), w] for d, w in sources],
            "config": asdict(cfg)}  # fmt: skip
    if init is not None:
        info["init"] = str(init)

    def save_last(epoch: int) -> None:
        save_checkpoint(last_dir, model, decode_cfg, {**info, "epoch": epoch})
        extra = {} if ema is None else {"ema": ema.state_dict()}
        save_state(last_dir / STATE, opt, sched, epoch, history, best, extra)

    bar = _progress_bar() if progress else None
    completed = start
    try:
        if bar is not None:
            bar.start()
        for epoch in range(start, cfg.epochs):
            model.train()
            # Each epoch's shuffle and augmentation depend only on (seed, epoch): a resumed run
            # sees the same data as one never interrupted.
            epoch_seed = int(np.random.SeedSequence([cfg.seed, epoch]).generate_state(1)[0])
            gen.manual_seed(epoch_seed)
            ds.reseed(epoch_seed)
            task = (
                bar.add_task(
                    f"epoch {epoch + 1}/{cfg.epochs}", total=steps_per_epoch, loss=float("nan")
                )
                if bar
                else None
            )
            t0, sums, n = time.perf_counter(), {}, 0
            for x, target, weight in loader:
                with torch.autocast("cpu", dtype=torch.bfloat16, enabled=cfg.bf16):
                    maps = model(x)
                terms = detection_loss(maps.float(), target, weight)
                opt.zero_grad(set_to_none=True)
                terms["loss"].backward()
                opt.step()
                sched.step()
                if ema is not None:
                    ema.update_parameters(model)
                for k, v in terms.items():
                    sums[k] = sums.get(k, 0.0) + float(v.detach())
                n += 1
                if bar is not None:
                    bar.update(task, advance=1, loss=sums["loss"] / n)
            losses = {k: v / n for k, v in sums.items()}
            judged = model if ema is None else ema.module  # what best/ would hold
            metrics = validate(judged, val, decode_cfg, cfg.min_gate_px)
            score = _score(metrics)
            row = {"epoch": epoch + 1, "seconds": round(time.perf_counter() - t0, 1),
                   "loss": losses, "val": metrics, "score": round(score, 4)}  # fmt: skip
            history.append(row)
            _log_tb(writer, row, opt.param_groups[0]["lr"])
            if score > best[0]:
                best = (score, epoch + 1, metrics)
                save_checkpoint(
                    best_dir, judged, decode_cfg, {**info, "epoch": epoch + 1, "val": metrics}
                )
            save_last(epoch + 1)
            completed = epoch + 1
            atomic_write_json(out / "history.json", history)
            if log is not None:
                log(_epoch_line(row))
    except KeyboardInterrupt:
        save_last(completed)
        raise
    finally:
        if bar is not None:
            bar.stop()
        writer.close()
    best_model, _, meta = load_checkpoint(best_dir)
    if cfg.tune_decode:
        tuned, metrics = tune_decode(best_model, val, decode_cfg, cfg.min_gate_px)
        done = meta["training"]  # a finished run resumed is only tuned again
        default = done.get("val_default_decode", done.get("val"))
        info = {**done, "val": metrics, "val_default_decode": default}
        save_checkpoint(best_dir, best_model, tuned, info)
        best = (best[0], best[1], metrics)
        if log is not None:
            log(f"decoding thresholds tuned on val: {tuned}")
    export_onnx(best_model, out / "model.onnx")
    return TrainResult(out, len(history), best[1], best[2], history)


def data_sources(data) -> list[tuple[Path, float]]:
    """(folder, share) of each training source: a path, or a list of paths and (path, share)
    pairs.

    Raises:
        ValueError: a share that is not a number > 0.
    """
    items = list(data) if isinstance(data, list) else [data]
    out = []
    for item in items:
        path, share = (item, 1.0) if isinstance(item, str | Path) else item
        share = float(share)
        if not share > 0 or not np.isfinite(share):
            raise ValueError(f"{path}: a dataset's share must be a number > 0, got {share}")
        out.append((Path(path), share))
    return out


def sources_and_shares(data) -> tuple[list[Path], list[float] | None]:
    """The folders of the later stages' training ``data`` (as :func:`data_sources`: a path, or a
    list of paths and (path, share) pairs) and each one's share of the training draws: None
    where no item gives a share (every image alike, as without shares), else 1 where not given.

    Raises:
        ValueError: no folder, or as :func:`data_sources`.
    """
    items = data if isinstance(data, list) else [data]
    sources = data_sources(items)
    if not sources:
        raise ValueError("no training data given")
    given = any(not isinstance(item, str | Path) for item in items)
    return [d for d, _ in sources], [w for _, w in sources] if given else None


def warmup_cosine(
    opt: torch.optim.Optimizer, total_steps: int, warmup: int = 100
) -> torch.optim.lr_scheduler.LambdaLR:
    """``warmup`` linear warm-up steps, then cosine decay to 0 at ``total_steps`` (the schedule
    of every stage's training)."""
    return torch.optim.lr_scheduler.LambdaLR(
        opt,
        lambda s: float(
            min((s + 1) / warmup, 0.5 * (1 + np.cos(np.pi * min(s / total_steps, 1.0))))
        ),
    )


def run_folders(out: Path, resume: bool, state: str) -> tuple[Path, Path]:
    """``(OUT/last, OUT/best)`` of a training run, checked against ``resume``.

    Raises:
        FileNotFoundError: ``resume`` without ``OUT/last/<state>``.
        ValueError: a new run where one already is.
    """
    last_dir, best_dir = out / "last", out / "best"
    if resume and not (last_dir / state).is_file():
        raise FileNotFoundError(f"{last_dir / state}: nothing to resume")
    if not resume and (last_dir / state).is_file():
        raise ValueError(
            f"{out} already holds a training run; pass --resume or choose another --out"
        )
    return last_dir, best_dir


def save_state(
    path: Path, opt, sched, epoch: int, history: list, best: tuple, extra: dict | None = None
) -> None:
    """Write what a resumed run needs (optimizer, schedule, epoch, history, best so far) to
    ``path`` atomically; tensors and strings only, so it loads with ``weights_only=True``."""
    state = {"optimizer": opt.state_dict(), "scheduler": sched.state_dict(), "epoch": epoch,
             "history": json.dumps(history), "best_score": best[0], "best_epoch": best[1],
             "best_metrics": json.dumps(best[2]), **(extra or {})}  # fmt: skip
    with atomic_path(path) as tmp:
        torch.save(state, tmp)


def load_state(path: Path, opt, sched) -> tuple[int, list, tuple, dict]:
    """Restore ``opt`` and ``sched`` from :func:`save_state`'s file; returns (epochs done,
    history, (best score, best epoch, best metrics), the whole state)."""
    try:
        st = torch.load(path, weights_only=True)
        opt.load_state_dict(st["optimizer"])
        sched.load_state_dict(st["scheduler"])
        best = (float(st["best_score"]), int(st["best_epoch"]), json.loads(st["best_metrics"]))
        return int(st["epoch"]), json.loads(st["history"]), best, st
    except Exception as e:  # noqa: BLE001 - any unreadable state is a corrupt file for the user
        msg = str(e).splitlines()[0] if str(e) else type(e).__name__
        raise ValueError(f"{path}: corrupt training state ({type(e).__name__}: {msg})") from None


def _moving_average(model: CornerNet, decay: float) -> torch.optim.swa_utils.AveragedModel | None:
    """An exponential moving average of ``model``'s weights and buffers (None if decay is 0)."""
    if not 0.0 <= decay < 1.0:
        raise ValueError(f"ema_decay must be in [0, 1), got {decay}")
    if decay == 0.0:
        return None
    from torch.optim.swa_utils import AveragedModel, get_ema_multi_avg_fn

    return AveragedModel(model, multi_avg_fn=get_ema_multi_avg_fn(decay), use_buffers=True)


def _progress_bar():
    from rich.progress import (
        BarColumn,
        MofNCompleteColumn,
        Progress,
        TextColumn,
        TimeElapsedColumn,
        TimeRemainingColumn,
    )

    return Progress(
        TextColumn("[bold]{task.description}"), BarColumn(), MofNCompleteColumn(),
        TextColumn("loss {task.fields[loss]:.3f}"), TimeElapsedColumn(), TimeRemainingColumn(),
    )  # fmt: skip


def _log_tb(writer, row: dict, lr: float) -> None:
    e = row["epoch"]
    for k, v in row["loss"].items():
        writer.add_scalar(f"loss/{k}", v, e)
    m = row["val"]
    for k in ("precision", "recall"):
        if m[k] is not None:
            writer.add_scalar(f"val/{k}", m[k], e)
    for k, v in {**m["corner_error_px"], **{f"pck_{k}": v for k, v in m["pck"].items()}}.items():
        if v is not None:
            writer.add_scalar(f"val/{k}", v, e)
    writer.add_scalar("lr", lr, e)
    writer.flush()


def _epoch_line(row: dict) -> str:
    m = row["val"]
    return (
        f"epoch {row['epoch']}: loss {row['loss']['loss']:.3f}  val precision {m['precision']}  "
        f"recall {m['recall']}  median corner error {m['corner_error_px']['median']} px  "
        f"PCK@2px {m['pck']['2px']}  PCK@5px {m['pck']['5px']}  ({row['seconds']} s)"
    )
