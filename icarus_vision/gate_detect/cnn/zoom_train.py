"""Training the zoom stage (``zoom.py``) on a trained detector's own detections.

Examples: the detector (corner network and refiner) runs over the train splits; each detection
matched to a counted labelled gate (eval-detector's rule) gives its four corner patches, cut where
the detector put the gate, and ``copies`` more cut where its corners were moved further at random
(``jitter`` of the side), so that the corrections are learnt over a wider spread of errors than
the detector happens to make, and ``wide_copies`` more with one corner moved much further
(``wide_jitter``), as the refiner leaves a few. The patches are cut once and kept in
``OUT/examples.npz`` (arrays only, read without unpickling), so a resumed run does not run the
detector again; while they are being cut, every ``CHUNK`` images are kept in
``OUT/examples.parts/``, so a run interrupted then and started again with the same command
continues from them. Training flips half of them about their diagonal (a mirrored corner: the
target's two coordinates swap) and jitters brightness, contrast and noise. Every epoch is
validated as eval-detector would score the detector with the stage on the val split; at the end
the smallest gate it reads (``min_side_px``) is tuned there.
"""

from __future__ import annotations

import copy
import json
import shutil
from collections.abc import Callable, Iterator
from dataclasses import asdict, dataclass, fields, replace
from pathlib import Path

import numpy as np
import torch

from icarus_vision.fileio import atomic_write_npz
from icarus_vision.gate_detect.cnn.data import Split, load_split, load_splits, read_rgb
from icarus_vision.gate_detect.cnn.model import to_float
from icarus_vision.gate_detect.cnn.rectify import extract, to_tensor
from icarus_vision.gate_detect.cnn.stage_train import (
    dataset_digest,
    draw_order,
    load_keyed,
    run_epochs,
    save_keyed,
    weights_digest,
)
from icarus_vision.gate_detect.cnn.tune import SCORE_TIE
from icarus_vision.gate_detect.cnn.zoom import (
    ZoomConfig,
    ZoomNet,
    homographies,
    read,
    to_corners,
    to_targets,
    zoomable,
)
from icarus_vision.gate_detect.metrics import evaluate_image, mean_sides, summarize

STATE = "zoom_state.pt"
EXAMPLES = "examples.npz"
PARTS = "examples.parts"
CHUNK = 1000
"""Training images whose patches are saved together in ``OUT/examples.parts/`` while they are
cut (what an interrupted run keeps)."""
ZOOM_ONNX = "zoom.onnx"
MIN_SIDES = (20.0, 25.0, 30.0, 40.0, 60.0)
"""``ZoomConfig.min_side_px`` values tried on val, each with and without ``mirror`` (ties within
``tune.SCORE_TIE`` go to less work: no mirroring, then the larger)."""


@dataclass(frozen=True)
class ZoomTrainConfig:
    """Settings of one zoom-stage training run (recorded in ``detector.json``)."""

    epochs: int = 6
    """Passes over the examples."""
    seed: int = 0
    """Seed of the jitter, the initial weights, the shuffling and the augmentation."""
    batch_size: int = 256
    """Examples per optimisation step."""
    lr: float = 2e-3
    """Peak learning rate of AdamW (100 warm-up steps, then cosine decay to 0)."""
    weight_decay: float = 1e-4
    """AdamW weight decay."""
    copies: int = 2
    """Jittered copies of each detection."""
    jitter: float = 0.02
    """Standard deviation of their corners' noise, as a fraction of the gate's side."""
    wide_copies: int = 0
    """Copies more of each detection, each with one of its four corners (drawn at random) moved
    by ``wide_jitter`` instead: the refiner leaves about 1 % of corners more than 5 px off, mostly
    on gates of 20-30 px (a tenth to a third of the side), further than ``jitter`` teaches the
    stage to correct."""
    wide_jitter: float = 0.15
    """Standard deviation of the wide copies' moved corner's noise, as a fraction of the side."""
    limit: int | None = None
    """Use only the first ``limit`` images of each split (quick runs and tests)."""
    min_gate_px: float = 20.0
    """Smallest gate trained on and counted in the validation figures, pixels."""


CUTS = ("seed", "copies", "jitter", "min_gate_px", "wide_copies", "wide_jitter")
"""The :class:`ZoomTrainConfig` fields the training patches depend on (with the data and the
detector, the key of ``OUT/examples.parts/``)."""


@dataclass
class Examples:
    """Corner patches and where their corners truly are.

    Attributes:
        patches: (M, P, P, 3) uint8 corner patches
            (:func:`~icarus_vision.gate_detect.cnn.zoom.homographies`).
        targets: (M, 2) float32 true corner in each, half patches from its centre.
        weights: (M,) how often training draws each, its image's share / that dataset's images
            (None: each once an epoch).
    """

    patches: np.ndarray
    targets: np.ndarray
    weights: np.ndarray | None = None


@dataclass
class ValFrames:
    """The detector's output on the val split, for scoring it with the zoom stage.

    Attributes:
        detections: per image, (corners (4, 2), score) of each detection.
        truth: per image, (corners, visibility, distance) of each labelled gate.
        patches: (4K, P, P, 3) corner patches of the K detections at least ``min_gate_px``.
        back: (4K, 3, 3) their patch-to-camera homographies.
        owner: (K, 2) (image, detection) index of each of those detections.
    """

    detections: list[list[tuple[np.ndarray, float]]]
    truth: list[list[tuple]]
    patches: np.ndarray
    back: np.ndarray
    owner: np.ndarray


def detections(
    detector, split: Split, progress: bool = False, what: str = "", start: int = 0
) -> Iterator:
    """Per image of ``split`` (loaded without pixels) from index ``start`` on, the index, the
    image and the detector's (corners, score) list; an iterator, so that the images are not all
    kept."""
    from rich.progress import track

    items = enumerate(split.files[start:], start)
    if progress:
        items = track(items, total=len(split.files) - start, description=f"detecting {what}")
    for i, path in items:
        image = read_rgb(path)
        found = [(d.corners.astype(float), float(d.score)) for d in detector.detect(image)]
        yield i, image, found


def _truth(split: Split, i: int) -> list[tuple]:
    return [(g.corners, g.visibility, g.distance) for g in split.gates[i]]


def training_examples(
    detector,
    split: Split,
    cfg: ZoomConfig,
    tcfg: ZoomTrainConfig,
    rng: np.random.Generator,
    progress: bool = False,
    parts: Path | None = None,
    key: dict | None = None,
) -> Examples:
    """Corner patches of the detector's matched detections on ``split`` (module docstring).

    With ``parts``, the patches of every :data:`CHUNK` images are written there with ``key``
    (what they were cut from) and ``rng``'s state; parts already there with the same ``key``
    are read instead of running the detector again, and ``rng`` continues from where they left
    it: the same examples as one uninterrupted pass.
    """
    patches, targets = [], []
    start = 0
    while parts is not None:
        part = load_keyed(parts / f"{start // CHUNK:05d}.npz", key)
        if part is None:  # missing, unreadable or cut from something else: cut from here
            break
        patches.append(part["patches"])
        targets.append(part["targets"])
        rng.bit_generator.state = json.loads(str(part["rng"]))
        start += CHUNK
    chunk_p, chunk_t = [], []
    for i, image, found in detections(detector, split, progress, "train images", start):
        g_rec, _ = evaluate_image(found, _truth(split, i), tcfg.min_gate_px)
        for g in g_rec:
            if not (g["matched"] and g["evaluable"] and g["side"] >= tcfg.min_gate_px):
                continue
            q = g["pred_corners"][None]
            quads = np.concatenate([q, q + corner_noise(tcfg, rng) * g["side"]])
            h, _ = homographies(quads, cfg)
            t = to_targets(h, np.tile(g["corners"], (len(quads), 1)), cfg)
            ok = np.isfinite(t).all(axis=1) & (np.abs(t) < 1.5).all(axis=1)
            chunk_p.append(extract(image, h[ok], cfg))
            chunk_t.append(t[ok].astype(np.float32))
        if (i + 1) % CHUNK == 0 or i + 1 == len(split.files):
            p = _stack(chunk_p, (0, cfg.patch, cfg.patch, 3), np.uint8)
            t = _stack(chunk_t, (0, 2), np.float32)
            if parts is not None:
                parts.mkdir(parents=True, exist_ok=True)
                save_keyed(parts / f"{i // CHUNK:05d}.npz", key, patches=p, targets=t,
                           rng=np.array(json.dumps(rng.bit_generator.state)))  # fmt: skip
            patches.append(p)
            targets.append(t)
            chunk_p, chunk_t = [], []
    return Examples(_stack(patches, (0, cfg.patch, cfg.patch, 3), np.uint8),
                    _stack(targets, (0, 2), np.float32))  # fmt: skip


def corner_noise(tcfg: ZoomTrainConfig, rng: np.random.Generator) -> np.ndarray:
    """(copies + wide_copies, 4, 2) moves of one detection's corners for its jittered copies,
    fractions of its side: every corner by ``jitter``, except one corner of each wide copy, by
    ``wide_jitter``. The wide ones are drawn last: without them, the same draws as before."""
    noise = rng.normal(size=(tcfg.copies + tcfg.wide_copies, 4, 2)) * tcfg.jitter
    if tcfg.wide_copies:
        moved = rng.integers(0, 4, tcfg.wide_copies)
        wide = rng.normal(size=(tcfg.wide_copies, 2)) * tcfg.wide_jitter
        noise[np.arange(tcfg.copies, len(noise)), moved] = wide
    return noise


def _stack(arrays: list[np.ndarray], empty: tuple[int, ...], dtype) -> np.ndarray:
    """``arrays`` concatenated, or an empty array of shape ``empty``."""
    return np.concatenate(arrays) if arrays else np.zeros(empty, dtype)


def val_frames(
    detector, split: Split, cfg: ZoomConfig, min_gate_px: float, progress: bool = False
) -> ValFrames:
    """The detector's output on ``split`` and the corner patches of its detections."""
    dets, truth, patches, back, owner = [], [], [], [], []
    wide = replace(cfg, min_side_px=min_gate_px)
    for i, image, found in detections(detector, split, progress, "val images"):
        dets.append(found)
        truth.append(_truth(split, i))
        quads = np.array([c for c, _ in found], float).reshape(-1, 4, 2)
        use = np.flatnonzero(zoomable(quads, wide))
        if len(use):
            h, b = homographies(quads[use], cfg)
            patches.append(extract(image, h, cfg))
            back.append(b)
            owner += [(i, k) for k in use]
    p = cfg.patch
    return ValFrames(
        dets, truth,
        np.concatenate(patches) if patches else np.zeros((0, p, p, 3), np.uint8),
        np.concatenate(back) if back else np.zeros((0, 3, 3)),
        np.array(owner, int).reshape(-1, 2),
    )  # fmt: skip


def predict(net: ZoomNet, patches: np.ndarray, mirror: bool = False, batch: int = 1024):
    """(M, 2) outputs of ``net`` (eval mode) on (M, P, P, 3) uint8 patches; with ``mirror``, the
    mean of its readings of each patch as it is and mirrored about its diagonal (as
    :func:`~icarus_vision.gate_detect.cnn.zoom.sharpen` reads them)."""
    net.eval()
    out = [np.zeros((0, 2))]
    for s in range(0, len(patches), batch):
        out.append(read(net, to_float(patches[s : s + batch]), mirror))
    return np.concatenate(out)


def evaluate(net: ZoomNet, val: ValFrames, min_side_px: float, min_gate_px: float,
             outputs: np.ndarray | None = None) -> dict:  # fmt: skip
    """eval-detector figures of the detector on the val split with the zoom stage reading gates
    at least ``min_side_px`` across (``outputs``: the network's on ``val.patches``, if known)."""
    from icarus_vision.gate_detect.cnn.tune import score

    if outputs is None:
        outputs = predict(net, val.patches)
    moved = to_corners(val.back, outputs.astype(np.float64), net.cfg).reshape(-1, 4, 2)
    dets = [list(d) for d in val.detections]
    for (i, k), q in zip(val.owner, moved, strict=True):
        c, s = dets[i][k]
        if mean_sides(c) >= min_side_px:
            dets[i][k] = (q, s)
    gts, preds = [], []
    for d, t in zip(dets, val.truth, strict=True):
        g, p = evaluate_image(d, t, min_gate_px)
        gts += g
        preds += p
    m = summarize(gts, preds, min_gate_px)
    return {**m, "score": round(score(m), 4), "min_side_px": min_side_px}


def tune(net: ZoomNet, val: ValFrames, min_gate_px: float) -> tuple[ZoomConfig, dict]:
    """The ``min_side_px`` (``MIN_SIDES``) and ``mirror`` with the best val score (near ties:
    the least work) and its val figures."""
    tried = []
    for mirror in (False, True):  # in order of work
        outputs = predict(net, val.patches, mirror)
        for s in MIN_SIDES[::-1]:
            tried.append((replace(net.cfg, min_side_px=s, mirror=mirror),
                          evaluate(net, val, s, min_gate_px, outputs)))  # fmt: skip
    best = max(m["score"] for _, m in tried)
    return next((c, m) for c, m in tried if m["score"] >= best - SCORE_TIE)


def augment(x: torch.Tensor, y: torch.Tensor, rng: np.random.Generator):
    """Half the patches flipped about their diagonal (targets swapped), brightness, contrast
    and noise jitter; (N, 3, P, P) in [0, 1], (N, 2)."""
    n = len(x)
    flip = torch.from_numpy(rng.random(n) < 0.5)
    x = torch.where(flip[:, None, None, None], x.transpose(2, 3), x)
    y = torch.where(flip[:, None], y.flip(1), y)
    gain = torch.from_numpy(rng.uniform(0.6, 1.4, (n, 1, 1, 1))).float()
    bias = torch.from_numpy(rng.uniform(-0.15, 0.15, (n, 1, 1, 1))).float()
    noise = torch.from_numpy(rng.normal(size=x.shape) * rng.uniform(0, 0.04, (n, 1, 1, 1)))
    return ((x - 0.5) * gain + 0.5 + bias + noise.float()).clamp_(0, 1), y


def train_epoch(net, opt, sched, ex: Examples, rng, batch_size: int, on_step=None) -> float:
    """One shuffled pass over the examples (as many drawn by ``ex.weights`` where it has them);
    the mean L1 loss (half patches)."""
    net.train()
    order = draw_order(rng, len(ex.targets), ex.weights)
    total, n = 0.0, 0
    for s in range(0, len(order), batch_size):
        b = np.sort(order[s : s + batch_size])
        x, y = augment(to_tensor(ex.patches[b]), torch.from_numpy(ex.targets[b]), rng)
        loss = (net(x) - y).abs().sum(dim=1).mean()
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        sched.step()
        total, n = total + float(loss.detach()), n + 1
        if on_step is not None:
            on_step(total / n)
    return total / max(n, 1)


def _load_examples(path: Path) -> Examples:
    try:
        with np.load(path, allow_pickle=False) as z:
            return Examples(
                z["patches"], z["targets"], z["weights"] if "weights" in z.files else None
            )
    except (OSError, ValueError, KeyError) as e:
        raise ValueError(
            f"{path}: unreadable examples file ({e}); delete it to collect again"
        ) from None


@dataclass(frozen=True)
class ZoomResult:
    """What :func:`train_zoom` produced."""

    out_dir: Path
    best_epoch: int
    best_metrics: dict
    history: list[dict]


def train_zoom(
    detector: str | Path,
    data_dir: str | Path | list,
    out_dir: str | Path,
    val_dir: str | Path | None = None,
    epochs: int = 6,
    seed: int = 0,
    resume: bool = False,
    config: ZoomTrainConfig | None = None,
    zoom_config: ZoomConfig | None = None,
    progress: bool = True,
    log: Callable[[str], None] | None = None,
) -> ZoomResult:
    """Train (or resume training) the zoom stage of a trained detector.

    Output folder: ``best/`` and ``last/`` are complete detector checkpoints (the detector's
    networks copied, plus ``zoom.safetensors``); ``last/`` also holds ``zoom_state.pt`` (what
    ``resume`` reads); ``examples.npz`` (the training patches), ``zoom.onnx`` (best),
    ``history.json`` and TensorBoard logs in ``tb/``. Ctrl-C saves ``last/``; Ctrl-C while the
    patches are being cut keeps those of every :data:`CHUNK` images in ``examples.parts/``, and
    the same command started again continues from them; every epoch's
    shuffle and augmentation depend on (seed, epoch) alone, so a resumed run trains as one never
    interrupted.

    Args:
        detector: a trained detector with a refiner (checkpoint folder or file); its own zoom
            stage, if any, is ignored.
        data_dir: gen-dataset output whose ``train`` split is trained on; several: all of them,
            each a path or (path, share): each dataset's share of the training draws (patches
            drawn with replacement, each by its image's share / that dataset's images; without
            shares every patch once an epoch). A COCO-keypoints folder (labelled real images,
            ``import-gates``) joins training. Ideally images the detector was not trained on,
            so that its errors are those of unseen images.
        out_dir: output folder.
        val_dir: the dataset whose ``val`` split validates and tunes (default: the first
            ``data_dir``).
        epochs: total epochs (a resumed run continues to this number).
        seed: seed of jitter, weights, shuffling and augmentation.
        resume: continue from ``OUT/last`` with the run's own settings.
        config: further settings of a new run (``epochs`` and ``seed`` take precedence).
        zoom_config: architecture of a new zoom stage.
        progress: show rich progress bars.
        log: called with one line per epoch.

    Raises:
        FileNotFoundError / ValueError: bad detector or dataset, a detector without a refiner,
            or OUT/last present without ``resume`` (or missing with it).
    """
    from icarus_vision.gate_detect.cnn import CnnDetector
    from icarus_vision.gate_detect.cnn.checkpoint import (
        export_zoom_onnx,
        load_checkpoint,
        load_refiner,
        load_zoom,
        save_checkpoint,
    )
    from icarus_vision.gate_detect.cnn.train import (
        load_state,
        run_folders,
        save_state,
        sources_and_shares,
        warmup_cosine,
    )

    cfg = replace(config or ZoomTrainConfig(), epochs=epochs, seed=seed)
    if cfg.epochs < 1:
        raise ValueError(f"epochs must be >= 1, got {cfg.epochs}")
    out = Path(out_dir)
    last_dir, best_dir = run_folders(out, resume, STATE)
    source = last_dir if resume else detector
    corner_net, decode_cfg, meta = load_checkpoint(source)
    refiner = load_refiner(source, meta)
    if refiner is None:
        raise ValueError(f"{detector}: the zoom stage needs a detector with a refiner")
    torch.manual_seed(cfg.seed)
    net = ZoomNet(zoom_config or ZoomConfig())
    if resume:
        net = load_zoom(last_dir, meta).train()
        stored = meta.get("zoom_training", {}).get("config", {})
        known = {f.name for f in fields(ZoomTrainConfig)}
        cfg = replace(
            ZoomTrainConfig(**{k: v for k, v in stored.items() if k in known}), epochs=epochs
        )
    dirs, shares = sources_and_shares(data_dir)
    val_dir = dirs[0] if val_dir is None else val_dir
    # the detector folds batch norm into its own copy (the checkpoints keep the networks as they
    # are); threads=None leaves PyTorch's thread count to the training
    det = CnnDetector(copy.deepcopy(corner_net), decode_cfg, refiner=refiner, threads=None)
    out.mkdir(parents=True, exist_ok=True)
    val = val_frames(det, load_split(val_dir, "val", None, cfg.limit), net.cfg, cfg.min_gate_px,
                     progress)  # fmt: skip
    # a finished run resumed is only tuned again: no training patches needed
    finished = resume and meta.get("zoom_training", {}).get("epoch", 0) >= cfg.epochs
    train = None
    if resume and not finished and (out / EXAMPLES).is_file():
        train = _load_examples(out / EXAMPLES)
    elif not finished:
        rng = np.random.default_rng(cfg.seed)
        digest = weights_digest(corner_net, refiner)
        parts, weights = [], []
        for k, d in enumerate(dirs):
            split = load_splits([d], "train", None, cfg.limit, same_size=False)
            cuts = {f: getattr(cfg, f) for f in CUTS}
            key = {"data": str(d), "dataset": dataset_digest(d), "images": len(split.files),
                   "detector": digest, "zoom": net.cfg.to_dict(), **cuts}  # fmt: skip
            parts.append(training_examples(det, split, net.cfg, cfg, rng, progress,
                                           out / PARTS / str(k), key))  # fmt: skip
            if shares is not None:
                weights.append(np.full(len(parts[-1].targets), shares[k] / len(split.files)))
        train = Examples(np.concatenate([p.patches for p in parts]),
                         np.concatenate([p.targets for p in parts]),
                         np.concatenate(weights) if weights else None)  # fmt: skip
        drawn = {} if train.weights is None else {"weights": train.weights}
        atomic_write_npz(out / EXAMPLES, patches=train.patches, targets=train.targets, **drawn)
        shutil.rmtree(out / PARTS, ignore_errors=True)
        if not len(train.targets):
            raise ValueError(f"{dirs}: the detector matched no gate to train the zoom stage on")
    if log is not None and finished:
        log("a finished run: tuning it again ...")
    elif log is not None:
        log(f"{len(train.targets)} corner patches to train on, {len(val.patches)} to validate")
    opt = torch.optim.AdamW(net.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
    steps_per_epoch = 1 if finished else int(np.ceil(len(train.targets) / cfg.batch_size))
    sched = warmup_cosine(opt, cfg.epochs * steps_per_epoch)
    start, history, best = 0, [], (-1.0, -1, {})
    if resume:
        start, history, best, _ = load_state(last_dir / STATE, opt, sched)
    info = {"detector": str(detector), "data": [str(d) for d in dirs], "val_data": str(val_dir),
            "config": asdict(cfg)}  # fmt: skip
    if shares is not None:
        info["shares"] = shares

    def save(folder: Path, epoch: int, zoom: ZoomNet, extra: dict | None = None) -> None:
        save_checkpoint(folder, corner_net, decode_cfg, meta.get("training", {}), refiner,
                        meta.get("refine_training"), zoom,
                        {**info, "epoch": epoch, **(extra or {})})  # fmt: skip

    def save_last(epoch: int, best: tuple) -> None:
        save(last_dir, epoch, net)
        save_state(last_dir / STATE, opt, sched, epoch, history, best)

    def one_epoch(epoch: int, rng: np.random.Generator, step) -> tuple[dict, dict, float]:
        loss = train_epoch(net, opt, sched, train, rng, cfg.batch_size, step)
        metrics = evaluate(net, val, net.cfg.min_side_px, cfg.min_gate_px)
        return {"loss": loss}, metrics, metrics["score"]

    run_epochs(
        out, start, cfg.epochs, cfg.seed, steps_per_epoch, one_epoch,
        lambda epoch, metrics: save(best_dir, epoch, net, {"val": metrics}), save_last, history,
        best, "zoom", progress, log,
    )  # fmt: skip
    _, _, best_meta = load_checkpoint(best_dir)
    best_net = load_zoom(best_dir, best_meta)
    tuned_cfg, metrics = tune(best_net, val, cfg.min_gate_px)
    tuned = ZoomNet(tuned_cfg)
    tuned.load_state_dict(best_net.state_dict())
    done = best_meta["zoom_training"]  # a finished run resumed is only tuned again
    untuned = done.get("val_untuned", done.get("val"))
    save(best_dir, done["epoch"], tuned.eval(), {"val": metrics, "val_untuned": untuned})
    if log is not None:
        log(f"tuned on val: zoom stage reads gates of at least {tuned_cfg.min_side_px} px, "
            f"mirror {tuned_cfg.mirror} (score {metrics['score']})")  # fmt: skip
    export_zoom_onnx(tuned, out / ZOOM_ONNX)
    return ZoomResult(out, done["epoch"], metrics, history)
