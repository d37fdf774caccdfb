"""Training the rescorer (``rescore.py``) on a trained detector's candidates.

The detector (refiner and zoom stage) reads every image of the given splits as it would when
detecting, and each candidate becomes a row: its features and whether its zoomed corners match
a labelled gate (:func:`~icarus_vision.gate_detect.cnn.rescore.labels`). Use images none of the detector's networks was trained on: on its
own training images the refiner is surer than it will be on new ones. A tenth of the images
(chosen by ``seed``) is held out; the weights of the epoch with the lowest held-out loss are kept.
With shares of the data (:func:`train_rescorer`), each epoch draws its rows with replacement, each
by its image's share / that dataset's images (the held-out loss is not weighted).
The table is saved in OUT (``candidates.npz``) and reused by a run with the same detector and
data; while it is read, every thousand images' rows are saved in ``OUT/candidates.parts/``, so
the same command started again after Ctrl-C continues from the last full thousand.
"""

from __future__ import annotations

import shutil
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np
import torch

from icarus_vision.fileio import atomic_path
from icarus_vision.gate_detect.cnn.checkpoint import resolve, save_rescorer, sha256
from icarus_vision.gate_detect.cnn.data import load_splits, read_rgb
from icarus_vision.gate_detect.cnn.rescore import FEATURES, RescoreConfig, RescoreNet, labels
from icarus_vision.gate_detect.cnn.stage_train import draw_order

TABLE = "candidates.npz"
PARTS = "candidates.parts"
"""OUT's folder of the table's parts while it is read (removed once the table is saved)."""
PART = 1000
"""Images a part holds."""
LABELS = "matches any labelled gate"
"""What a row's label means (part of the table's key: a table labelled otherwise is read again)."""


@dataclass(frozen=True)
class RescoreTrainConfig:
    """How the rescorer is trained (recorded in ``detector.json``'s ``rescore_training``)."""

    epochs: int = 40
    batch_size: int = 512
    lr: float = 3e-3
    weight_decay: float = 1e-4
    seed: int = 0
    holdout: float = 0.1
    """Fraction of the images held out to choose the epoch."""
    limit: int | None = None
    """Only the first N images of each split (quick runs)."""


def labelled_images(data: Path, splits: list[str], limit: int | None) -> list[tuple]:
    """(image file, labelled gates) of each image of a dataset's ``splits`` (a COCO-keypoints
    folder: its images, as ``train``)."""
    items = []
    for split in splits:
        s = load_splits([data], split, None, limit, same_size=False)
        items += zip(s.files, s.gates, strict=True)
    return items


def collect(detector, items: list[tuple], progress: bool = False, parts: Path | None = None,
            key: str = "") -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # fmt: skip
    """(features (N, F), labels (N,) 1/0, image number (N,)) of every candidate the detector
    reads in ``items``' images (:func:`labelled_images`). With ``parts`` (a folder), each
    :data:`PART` images' rows are saved there as they are read, under ``key``, and parts saved
    under the same key are read back instead: an interrupted run continues where it stopped."""
    from rich.progress import track

    if not items:
        raise ValueError("no images to read: check --data and --splits")
    if parts is not None:
        parts.mkdir(parents=True, exist_ok=True)
    chunks = range(0, len(items), PART)
    if progress:
        chunks = track(chunks, description=f"reading {len(items)} images, {PART} a part")
    xs, ys, imgs = [], [], []
    for start in chunks:
        f = None if parts is None else parts / f"{start // PART:05d}.npz"
        if f is not None and f.is_file():
            with np.load(f) as z:
                if str(z["key"]) == key:
                    xs.append(z["x"])
                    ys.append(z["y"])
                    imgs.append(z["image"])
                    continue
        px, py, pi = [np.zeros((0, len(FEATURES)))], [np.zeros(0, int)], [np.zeros(0, int)]
        for n, (path, gates) in enumerate(items[start : start + PART], start):
            x, zoomed = detector.candidate_table(read_rgb(path))
            px.append(x)
            py.append(labels(zoomed, [(g.corners, g.visibility, g.distance) for g in gates]))
            pi.append(np.full(len(x), n))
        px, py, pi = np.concatenate(px), np.concatenate(py), np.concatenate(pi)
        if f is not None:
            with atomic_path(f) as tmp, open(tmp, "wb") as fh:
                np.savez(fh, x=px, y=py, image=pi, key=np.array(key))
        xs.append(px)
        ys.append(py)
        imgs.append(pi)
    return np.concatenate(xs), np.concatenate(ys), np.concatenate(imgs)


def fit(x: np.ndarray, y: np.ndarray, image: np.ndarray, net_cfg: RescoreConfig,
        cfg: RescoreTrainConfig,
        image_weights: np.ndarray | None = None) -> tuple[RescoreNet, list[dict]]:  # fmt: skip
    """Train a rescorer on labelled rows (labels 1/0), holding out ``cfg.holdout`` of the
    images; the net of the best held-out epoch and the history. With ``image_weights`` (per
    image number), each epoch draws its rows in proportion to their image's weight."""

    rng = np.random.default_rng(cfg.seed)
    torch.manual_seed(cfg.seed)
    images = np.unique(image)
    held = np.isin(image, rng.choice(images, max(1, int(cfg.holdout * len(images))), False))
    mean, std = x[~held].mean(0), np.maximum(x[~held].std(0), 1e-6)
    net = RescoreNet(replace(net_cfg, mean=tuple(map(float, mean)), std=tuple(map(float, std))))
    opt = torch.optim.AdamW(net.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, cfg.epochs)
    xt, yt = (
        torch.tensor(x[~held], dtype=torch.float32),
        torch.tensor(y[~held], dtype=torch.float32),
    )
    xh, yh = torch.tensor(x[held], dtype=torch.float32), torch.tensor(y[held], dtype=torch.float32)
    weights = None if image_weights is None else image_weights[image[~held]]
    loss_fn = torch.nn.functional.binary_cross_entropy_with_logits
    best, best_state, history = np.inf, None, []
    for epoch in range(1, cfg.epochs + 1):
        net.train()
        order = torch.from_numpy(draw_order(rng, len(xt), weights))
        total = 0.0
        for i in range(0, len(order), cfg.batch_size):
            b = order[i : i + cfg.batch_size]
            loss = loss_fn(net(xt[b]), yt[b])
            opt.zero_grad()
            loss.backward()
            opt.step()
            total += loss.item() * len(b)
        sched.step()
        net.eval()
        with torch.no_grad():
            logit = net(xh)
            held_loss = float(loss_fn(logit, yh))
            acc = float(((logit > 0).float() == yh).float().mean())
        history.append({"epoch": epoch, "loss": total / len(xt), "held_out_loss": held_loss,
                        "held_out_accuracy": acc})  # fmt: skip
        if held_loss < best:
            best, best_state = held_loss, {k: v.clone() for k, v in net.state_dict().items()}
    net.load_state_dict(best_state)
    return net.eval(), history


def train_rescorer(
    detector_path: str | Path,
    data: list,
    out: Path,
    splits: list[str],
    net_cfg: RescoreConfig = RescoreConfig(),
    cfg: RescoreTrainConfig = RescoreTrainConfig(),
    progress: bool = True,
    log=print,
    backend: str = "auto",
) -> tuple[Path, list[dict]]:
    """Copy the detector at ``detector_path`` to ``out``, train a rescorer on its candidates in
    ``data``'s ``splits`` and add it there; returns (out, history).

    ``data``: gen-dataset folders and COCO-keypoints folders (labelled real images, read as
    ``train``), each a path or (path, share): each dataset's share of the training draws (rows
    drawn with replacement, each by its image's share / that dataset's images; without shares
    every row once an epoch)."""
    from icarus_vision.gate_detect.cnn import CnnDetector
    from icarus_vision.gate_detect.cnn.train import sources_and_shares

    src = resolve(detector_path)
    if not data:
        raise ValueError("train-rescorer needs at least one --data folder")
    data, shares = sources_and_shares(data)
    for d in data:
        if not Path(d).is_dir():
            raise FileNotFoundError(f"{d}: dataset folder not found")
    per_set = [labelled_images(d, splits, cfg.limit) for d in data]
    image_weights = None
    if shares is not None:
        image_weights = np.concatenate(
            [np.full(len(s), w / len(s)) for s, w in zip(per_set, shares, strict=True)]
        )
    out.mkdir(parents=True, exist_ok=True)
    detector = CnnDetector.load(src, backend=backend)
    key = {"detector": [sha256(src / f) for f in sorted(p.name for p in src.glob("*.safetensors"))
                        if f != "rescore.safetensors"],
           "data": [str(d) for d in data], "splits": list(splits), "limit": cfg.limit,
           "backend": detector.backend, "features": list(FEATURES), "labels": LABELS}  # fmt: skip
    table = out / TABLE
    x = None
    if table.is_file():
        with np.load(table) as z:
            if str(z["key"]) == repr(key):
                x, y, image = z["x"], z["y"], z["image"]
                log(f"reusing the candidates in {table}")
    if x is None:
        items = [item for s in per_set for item in s]
        x, y, image = collect(detector, items, progress, out / PARTS, repr(key))
        with atomic_path(table) as tmp, open(tmp, "wb") as f:
            np.savez(f, x=x, y=y, image=image, key=np.array(repr(key)))
        shutil.rmtree(out / PARTS, ignore_errors=True)
    if not len(y):
        raise ValueError(f"the detector at {src} proposed no candidate to learn from in {data}")
    log(f"{len(y)} candidates ({int(y.sum())} gates) from {image.max() + 1} images")
    net, history = fit(x, y, image, net_cfg, cfg, image_weights)
    for f in src.iterdir() if out.resolve() != src.resolve() else ():
        if f.is_file() and f.name not in ("rescore.safetensors", TABLE):
            shutil.copy2(f, out / f.name)
    record = {"detector": str(detector_path), "data": [str(d) for d in data], "splits": splits,
              "config": asdict(cfg), "candidates": len(y), "labels": LABELS, "backend": detector.backend,
              "best": min(history, key=lambda h: h["held_out_loss"])}  # fmt: skip
    if shares is not None:
        record["shares"] = shares
    save_rescorer(out, net, record)
    return out, history
