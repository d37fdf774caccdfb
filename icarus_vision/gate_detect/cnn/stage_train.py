"""What the trainers of the detector's later stages (refiner, zoom stage, rescorer) share: the
draws of an epoch's examples (:func:`draw_order`), the epoch loop with its progress bar,
TensorBoard logs, best and last checkpoints, history and Ctrl-C saving (their schedule is
``train.warmup_cosine``), and their caches of the earlier stages' output: arrays saved with the
key they were computed from (:func:`save_keyed`), keyed by the networks' weights among others
(:func:`weights_digest`)."""

from __future__ import annotations

import hashlib
import json
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch

from icarus_vision.fileio import atomic_write_json, atomic_write_npz


def weights_digest(*nets: torch.nn.Module) -> str:
    """SHA-256 of networks' weights (names, shapes and values): what a cache of their outputs
    is keyed by."""
    h = hashlib.sha256()
    for net in nets:
        for name, t in sorted(net.state_dict().items()):
            h.update(name.encode())
            h.update(str(tuple(t.shape)).encode())
            h.update(t.detach().contiguous().cpu().numpy().tobytes())
    return h.hexdigest()


def dataset_digest(data_dir: str | Path) -> str:
    """SHA-256 of a gen-dataset folder's ``manifest.json`` (its seed, recipe, splits and shard
    checksums; "none" without one): what a cache of outputs over its images is keyed by, so a
    dataset generated again at the same path does not match."""
    try:
        return hashlib.sha256((Path(data_dir) / "manifest.json").read_bytes()).hexdigest()
    except OSError:
        return "none"


def save_keyed(path: Path, key: dict, **arrays: np.ndarray) -> None:
    """Write ``arrays`` and what they were computed from (``key``, JSON) to ``path`` atomically."""
    atomic_write_npz(path, key=np.array(json.dumps(key, sort_keys=True)), **arrays)


def load_keyed(path: Path, key: dict) -> dict[str, np.ndarray] | None:
    """The arrays :func:`save_keyed` wrote at ``path`` if they were computed from ``key``; None
    if they were not, or the file is missing or unreadable (compute them again)."""
    try:
        with np.load(path, allow_pickle=False) as z:
            if str(z["key"]) != json.dumps(key, sort_keys=True):
                return None
            return {k: z[k] for k in z.files if k != "key"}
    except (OSError, ValueError, KeyError):
        return None


def draw_order(rng: np.random.Generator, n: int, weights: np.ndarray | None = None) -> np.ndarray:
    """The ``n`` examples of one epoch, in the order trained on: a permutation of all of them
    (``weights`` None), or ``n`` drawn with replacement in proportion to ``weights`` (N,) (each
    example its image's ``Split.weights``: every dataset its share of the draws, as the corner
    network's sampler draws images)."""
    if weights is None or not n:
        return rng.permutation(n)
    return rng.choice(n, n, p=weights / weights.sum())


EpochFn = Callable[[int, np.random.Generator, Callable[[float], None]], tuple[dict, dict, float]]
"""``one_epoch(epoch, rng, step) -> (mean loss terms with a "loss" key, val metrics, score)``;
``step(mean loss so far)`` is called after every optimisation step."""


def run_epochs(
    out: Path,
    first: int,
    epochs: int,
    seed: int,
    steps_per_epoch: int,
    one_epoch: EpochFn,
    save_best: Callable[[int, dict], None],
    save_last: Callable[[int, tuple], None],
    history: list,
    best: tuple,
    tag: str,
    progress: bool = True,
    log: Callable[[str], None] | None = None,
) -> tuple:
    """Train epochs ``first`` + 1 to ``epochs`` of a run.

    Each epoch calls ``one_epoch`` with a generator seeded by (seed, epoch) alone, so a resumed
    run trains as one never interrupted; appends a row to ``history`` and writes it to
    ``out/history.json``; logs the loss terms and val figures to TensorBoard (``out/tb``, tags
    ``<tag>_loss/...`` and ``<tag>_val/...``); calls ``save_best(epoch, metrics)`` on a better
    score, then ``save_last(epoch, best)``. Ctrl-C calls ``save_last`` for the epochs done and
    re-raises.

    Args:
        best: (score, epoch, metrics) so far ((-1.0, -1, {}) for a new run).

    Returns:
        The best (score, epoch, metrics).
    """
    from torch.utils.tensorboard import SummaryWriter

    from icarus_vision.gate_detect.cnn.train import _progress_bar

    writer = SummaryWriter(str(out / "tb"))
    bar = _progress_bar() if progress else None
    completed = first
    try:
        if bar is not None:
            bar.start()
        for epoch in range(first, epochs):
            task = None
            if bar is not None:
                task = bar.add_task(f"epoch {epoch + 1}/{epochs}", total=steps_per_epoch,
                                    loss=float("nan"))  # fmt: skip

            def step(loss: float, task=task) -> None:
                if bar is not None:
                    bar.update(task, advance=1, loss=loss)

            t0 = time.perf_counter()
            losses, metrics, score = one_epoch(epoch, np.random.default_rng([seed, epoch]), step)
            row = {"epoch": epoch + 1, "seconds": round(time.perf_counter() - t0, 1),
                   "loss": losses, "val": metrics, "score": round(score, 4)}  # fmt: skip
            history.append(row)
            for k, v in losses.items():
                writer.add_scalar(f"{tag}_loss/{k}", v, epoch + 1)
            writer.add_scalar(f"{tag}_val/score", score, epoch + 1)
            for k, v in metrics.get("pck", {}).items():
                if v is not None:
                    writer.add_scalar(f"{tag}_val/pck_{k}", v, epoch + 1)
            writer.flush()
            if score > best[0]:
                best = (score, epoch + 1, metrics)
                save_best(epoch + 1, metrics)
            save_last(epoch + 1, best)
            completed = epoch + 1
            atomic_write_json(out / "history.json", history)
            if log is not None:
                m = metrics
                log(f"epoch {epoch + 1}: loss {losses['loss']:.4f}  val precision "
                    f"{m['precision']}  recall {m['recall']}  median corner error "
                    f"{m['corner_error_px']['median']} px  PCK@2px {m['pck']['2px']}  "
                    f"PCK@5px {m['pck']['5px']}  ({row['seconds']} s)")  # fmt: skip
    except KeyboardInterrupt:
        save_last(completed, best)
        raise
    finally:
        if bar is not None:
            bar.stop()
        writer.close()
    return best
