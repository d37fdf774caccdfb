"""Training the refiner (``refine.py``) on a trained corner network's candidates.

Examples: the first stage runs over a dataset with loose decoding thresholds (``CANDIDATES``);
each candidate is labelled a gate when its corners lie within ``MATCH`` of a labelled gate's side
(mean corner distance), and that gate's corners are its regression target. Every epoch also adds
the labelled gates themselves with jittered corners (``JITTER``), so that the corrections are
learnt over a wider spread of errors than the first stage happens to make. Patches are cut anew
each epoch, the candidates jittered slightly, half of them mirrored (the corner order swapped
with the patch), with brightness, contrast and noise jitter.
"""

from __future__ import annotations

import copy
import ctypes
import itertools
from collections.abc import Callable
from dataclasses import asdict, dataclass, fields, replace
from pathlib import Path

import numpy as np
import torch

from icarus_vision.gate_detect.base import FLIP_ORDER
from icarus_vision.gate_detect.cnn.data import Split
from icarus_vision.gate_detect.cnn.decode import DecodeConfig, decode, in_frame
from icarus_vision.gate_detect.cnn.model import network_input
from icarus_vision.gate_detect.cnn.rectify import (
    corners_to_offsets,
    extract,
    homographies,
    mirrored,
    to_tensor,
    usable,
)
from icarus_vision.gate_detect.cnn.refine import (
    RefineConfig,
    RefineNet,
    Verdicts,
    geometry,
    select,
    stage_scores,
    verdicts,
)
from icarus_vision.gate_detect.cnn.stage_train import (
    dataset_digest,
    draw_order,
    load_keyed,
    run_epochs,
    save_keyed,
    weights_digest,
)
from icarus_vision.gate_detect.metrics import evaluate_image, mean_sides, summarize

CANDIDATES = DecodeConfig(
    centre_threshold=0.2, corner_threshold=0.2, snap_radius=0.4, min_snapped=0, sure_centre=1.0,
    nested_residual=0.08,
)  # fmt: skip
"""Loose first-stage decoding: the refiner, not the thresholds, decides."""
MATCH = 0.5
"""A candidate is a gate when its mean corner distance to a labelled gate is at most this
fraction of that gate's mean side (looser than eval-detector's rule: the refiner can move the
corners there, and duplicates of one gate fall to the overlap test once corrected)."""
SMALL_PX = 16.0
"""Examples whose candidate is smaller than this (mean side, pixels) weigh ``SMALL_WEIGHT`` in the
loss: eval-detector counts no gate under 20 px, and their labels are the noisiest."""
SMALL_WEIGHT = 0.25
JITTER = (0.02, 0.15)
"""Corner noise of the jittered labelled gates: per gate, a standard deviation drawn from this
range, as a fraction of the gate's side."""
STATE = "refine_state.pt"
REFINER_ONNX = "refiner.onnx"
CANDIDATE_CACHE = "candidates.npz"
"""The training split's labelled candidates, kept so that a resumed run (or a new one in a folder
holding them) need not find them again."""
TRAIN_IMAGES = "train-images.npy"
"""The training split's images, mapped from disk (``RefineTrainConfig.images_on_disk``)."""


@dataclass
class Candidates:
    """First-stage candidates of a split, labelled.

    Attributes:
        image: (N,) index of the image each candidate is in.
        quads: (N, 4, 2) candidate corners, camera pixels.
        targets: (N, 4, 2) corners of the matched labelled gate (NaN: not a gate).
        scores: (N, 3) first-stage scores (:func:`~icarus_vision.gate_detect.cnn.refine.stage_scores`).
        per_image: per image, the first stage's ``(gates, peaks)`` (for validation).
    """

    image: np.ndarray
    quads: np.ndarray
    targets: np.ndarray
    scores: np.ndarray
    per_image: list


def _release_free_memory() -> None:
    """Hand freed heap memory back to the system (glibc ``malloc_trim``; elsewhere nothing).

    Decoding thousands of images keeps a few small arrays of each alive among large freed
    buffers; glibc then keeps the whole heap, about 1 MB per image (20,000 training images ran
    out of 24 GB). Trimming after each batch keeps it at a few kB per image."""
    try:
        ctypes.CDLL("libc.so.6").malloc_trim(0)
    except (OSError, AttributeError):
        pass


def first_stage(
    model: torch.nn.Module,
    images: np.ndarray,
    cfg: DecodeConfig,
    batch: int = 32,
    input_size: tuple[int, int] | None = None,
):
    """Per image ``(gates, peaks)`` of the corner network (eval) decoded with ``cfg``, camera
    pixels; the network reads the images resized to ``input_size`` (None: as they are), as
    :class:`~icarus_vision.gate_detect.cnn.CnnDetector` does."""
    out = []
    h, w = images.shape[1:3]
    with torch.inference_mode():
        for i in range(0, len(images), batch):
            x = images[i : i + batch]
            # resized, or copied: the images may be mapped read-only
            x = np.stack([network_input(im, input_size) for im in x]) if input_size else np.array(x)
            maps = model(torch.from_numpy(x).permute(0, 3, 1, 2).float() / 255.0)
            for m in maps:
                out.append(
                    decode(m.float(), cfg, (w / m.shape[-1], h / m.shape[-2]), with_peaks=True)
                )
            del x, maps
            _release_free_memory()
    return out


def label(quads: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """(N, 4, 2) targets of (N, 4, 2) candidates among (G, 4, 2) labelled gates (MATCH rule);
    NaN for a candidate that is no gate."""
    targets = np.full(quads.shape, np.nan)
    truth = truth[np.isfinite(truth).all(axis=(1, 2))]
    if not len(truth) or not len(quads):
        return targets
    d = (
        np.linalg.norm(quads[:, None] - truth[None], axis=-1).mean(axis=-1)
        / mean_sides(truth)[None]
    )
    j = d.argmin(axis=1)
    ok = d[np.arange(len(quads)), j] <= MATCH
    targets[ok] = truth[j[ok]]
    return targets


def collect(
    model: torch.nn.Module,
    split: Split,
    cfg: DecodeConfig = CANDIDATES,
    input_size: tuple[int, int] | None = None,
) -> Candidates:
    """Run the first stage over ``split`` (loaded at camera resolution; the network reads it
    resized to ``input_size``, None: as it is) and label its candidates."""
    per_image = first_stage(model, split.images, cfg, input_size=input_size)
    idx, quads, targets, scores = [], [], [], []
    for i, ((gates, _), truth) in enumerate(zip(per_image, split.gates, strict=True)):
        q = np.array([g[0] for g in gates], float).reshape(-1, 4, 2)
        ok = usable(q)
        t = np.array([g.corners for g in truth], float).reshape(-1, 4, 2)
        idx.append(np.full(ok.sum(), i))
        quads.append(q[ok])
        targets.append(label(q[ok], t))
        scores.append(stage_scores(gates)[ok])
    return Candidates(np.concatenate(idx), np.concatenate(quads), np.concatenate(targets),
                      np.concatenate(scores), per_image)  # fmt: skip


def save_candidates(path: Path, cands: Candidates, key: dict) -> None:
    """Write the arrays of ``cands`` (not ``per_image``) and what they were collected from
    (``key``) to ``path`` atomically."""
    save_keyed(path, key, image=cands.image, quads=cands.quads, targets=cands.targets,
               scores=cands.scores)  # fmt: skip


def load_candidates(path: Path, key: dict) -> Candidates | None:
    """The candidates saved at ``path`` if they were collected from ``key`` (else, or if the
    file is missing or unreadable, None: collect them again)."""
    z = load_keyed(path, key)
    return None if z is None else Candidates(z["image"], z["quads"], z["targets"], z["scores"], [])


def jittered_truth(split: Split, rng: np.random.Generator, min_side_px: float = 8.0):
    """Labelled gates (side >= ``min_side_px``, finite) with noisy corners: (image idx, quads,
    targets)."""
    idx, t = [], []
    for i, gates in enumerate(split.gates):
        for g in gates:
            if np.isfinite(g.corners).all() and mean_sides(g.corners) >= min_side_px:
                idx.append(i)
                t.append(g.corners)
    idx, t = np.array(idx, int), np.array(t, float).reshape(-1, 4, 2)
    sigma = rng.uniform(*JITTER, size=len(t)) * mean_sides(t)
    q = t + rng.normal(size=t.shape) * sigma[:, None, None]
    ok = usable(q)
    return idx[ok], q[ok], t[ok]


def make_batch(
    images: np.ndarray,
    idx: np.ndarray,
    quads: np.ndarray,
    targets: np.ndarray,
    scores: np.ndarray,
    cfg: RefineConfig,
    rng: np.random.Generator | None,
):
    """Patches, geometry inputs, labels (N,), offset targets (N, 8) (NaN rows: no gate) and loss
    weights (N,) of some examples; with ``rng``, augmented (module docstring)."""
    quads, targets = quads.copy(), targets.copy()
    side = mean_sides(quads)
    weight = np.where(side >= SMALL_PX, 1.0, SMALL_WEIGHT).astype(np.float32)
    w = images.shape[2]
    seen = quads  # where each candidate lies, for the geometry inputs
    if rng is not None:
        moved = quads + rng.normal(size=quads.shape) * (0.015 * side)[:, None, None]
        ok = usable(moved)
        quads[ok] = moved[ok]
        seen = quads.copy()
        flip = rng.random(len(quads)) < 0.5  # half of them read mirrored
        quads[flip], seen[flip] = mirrored(quads[flip], w)
        targets[flip] = targets[flip][:, FLIP_ORDER]
    h = homographies(quads, cfg)
    patches = np.concatenate(
        [extract(images[i], h[k : k + 1], cfg) for k, i in enumerate(idx)]
    ) if len(idx) else np.zeros((0, cfg.patch, cfg.patch, 3), np.uint8)  # fmt: skip
    x = to_tensor(patches)
    if rng is not None and len(x):
        n = len(x)
        gain = torch.from_numpy(rng.uniform(0.6, 1.4, (n, 1, 1, 1))).float()
        bias = torch.from_numpy(rng.uniform(-0.15, 0.15, (n, 1, 1, 1))).float()
        colour = torch.from_numpy(rng.uniform(0.85, 1.15, (n, 3, 1, 1))).float()
        noise = torch.from_numpy(rng.normal(size=x.shape) * rng.uniform(0, 0.04, (n, 1, 1, 1)))
        x = ((x - 0.5) * gain * colour + 0.5 + bias + noise.float()).clamp_(0, 1)
    gate = np.isfinite(targets).all(axis=(1, 2))
    off = np.full((len(idx), 8), np.nan)
    if gate.any():
        off[gate] = corners_to_offsets(h[gate], targets[gate], cfg)
    geom = torch.from_numpy(geometry(seen, scores, (w, images.shape[1]), cfg))
    label = torch.from_numpy(gate.astype(np.float32))
    return x, geom, label, torch.from_numpy(off).float(), torch.from_numpy(weight)


def loss_terms(
    out: torch.Tensor,
    label: torch.Tensor,
    off: torch.Tensor,
    real: torch.Tensor,
    weight: torch.Tensor | None = None,
) -> dict:
    """Gate BCE over the real candidates (``real`` (N,) bool), smooth-L1 corner offsets over the
    gates (offsets within one side), each a mean weighted by ``weight`` (N,) (default 1)."""
    w = torch.ones_like(label) if weight is None else weight
    cls = torch.zeros((), dtype=out.dtype)
    if real.any():
        bce = torch.nn.functional.binary_cross_entropy_with_logits(
            out[real, 0], label[real], reduction="none"
        )
        cls = (w[real] * bce).sum() / w[real].sum()
    use = torch.isfinite(off).all(dim=1) & (off.abs() <= 1.0).all(dim=1)
    reg = torch.zeros((), dtype=out.dtype)
    if use.any():
        l1 = torch.nn.functional.smooth_l1_loss(out[use, 1:], off[use], beta=0.02, reduction="none")
        reg = (w[use] * l1.mean(dim=1)).sum() / w[use].sum()
    return {"loss": cls + 10.0 * reg, "gate": cls, "corners": reg}


def evaluate(
    net: torch.nn.Module,
    split: Split,
    per_image: list,
    cfg: RefineConfig,
    min_gate_px: float = 20.0,
    nms_iou: float = 0.5,
    read: list[Verdicts] | None = None,
    max_outside_px: float | None = DecodeConfig.max_outside_px,
) -> dict:
    """eval-detector figures of first stage + refiner on ``split`` (first-stage output given;
    ``read``: the refiner's verdicts on it too, read at a floor no higher than
    ``cfg.threshold``), reporting gates :func:`~icarus_vision.gate_detect.cnn.decode.in_frame`
    as the detector does."""
    net.eval()
    if read is None:
        read = [
            verdicts(net, im, gates, cfg)
            for im, (gates, _) in zip(split.images, per_image, strict=True)
        ]
    gts, preds = [], []
    for v, (_, peaks), truth in zip(read, per_image, split.gates, strict=True):
        found = in_frame(select(v, peaks, cfg, nms_iou), split.image_size, max_outside_px)
        t = [(g.corners, g.visibility, g.distance) for g in truth]
        g_rec, p_rec = evaluate_image([(c, s) for c, _, s in found], t, min_gate_px)
        gts += g_rec
        preds += p_rec
    return {**summarize(gts, preds, min_gate_px), "detections": len(preds)}


THRESHOLDS = (0.15, 0.2, 0.25, 0.3, 0.35, 0.4)
SNAPS = (0.0, 0.05)
MIRRORS = (False, True)
PASSES = (1, 2)
SKEWS = (0.0, 0.4)
INPUT_SCALES = (1.0, 0.8)
"""Corner-network input sizes tried by :func:`tune`, as fractions of the camera frame (the
network is convolutional; the refiner reads the full frame, so the first stage's precision
matters less than its speed)."""


def input_sizes(image_size: tuple[int, int], scales: tuple[float, ...] = INPUT_SCALES):
    """(W, H) corner-network input sizes, one per scale of ``image_size``."""
    return [(round(image_size[0] * s), round(image_size[1] * s)) for s in scales]


def tune(
    net,
    split: Split,
    per_size: dict[tuple[int, int], list],
    cfg: RefineConfig,
    min_gate_px: float = 20.0,
    mirrors: tuple[bool, ...] = MIRRORS,
    passes: tuple[int, ...] = PASSES,
) -> tuple[RefineConfig, tuple[int, int], dict]:
    """The gate threshold, snap radius, squareness check, mirrored reading, passes (grids above)
    and the corner network's input size with the best validation score
    (:func:`~icarus_vision.gate_detect.cnn.tune.score`); near-ties go to the fewest
    detections, then to the first tried (the first input size, no mirroring, one pass, the
    higher threshold, no check). The refiner reads the split once per input size, mirroring and
    number of passes.

    Args:
        per_size: first-stage output on ``split`` (:func:`first_stage`, decoded with
            ``cfg.candidate_iou``) per corner-network input size (W, H).

    Returns:
        (refiner config, input size, its val metrics).
    """
    from icarus_vision.gate_detect.cnn.tune import choose

    net.eval()
    tried = []
    for size, per_image in per_size.items():
        for m in mirrors:
            for k in passes:
                c = replace(cfg, mirror=m, passes=k)
                read = [verdicts(net, im, g, c, floor=min(THRESHOLDS))
                        for im, (g, _) in zip(split.images, per_image, strict=True)]  # fmt: skip
                for t, s, q in itertools.product(THRESHOLDS[::-1], SNAPS, SKEWS):
                    c = replace(cfg, threshold=t, snap=s, mirror=m, passes=k, max_skew=q)
                    metrics = evaluate(net, split, per_image, c, min_gate_px, read=read)
                    tried.append(((c, size), metrics))
    (best, size), metrics = choose(tried)
    return best, size, metrics


def train_epoch(
    net: torch.nn.Module,
    opt: torch.optim.Optimizer,
    sched,
    split: Split,
    cands: Candidates,
    cfg: RefineConfig,
    rng: np.random.Generator,
    batch_size: int = 256,
    on_step=None,
) -> dict:
    """One pass over the candidates plus freshly jittered labelled gates (as many drawn in
    proportion to their images' ``split.weights`` where it has them); mean loss terms."""
    j_idx, j_q, j_t = jittered_truth(split, rng)
    idx = np.concatenate([cands.image, j_idx])
    quads = np.concatenate([cands.quads, j_q])
    targets = np.concatenate([cands.targets, j_t])
    # jittered gates take the scores of random real gate candidates, and teach no classification
    pos = np.flatnonzero(np.isfinite(cands.targets).all(axis=(1, 2)))
    j_scores = (
        cands.scores[rng.choice(pos, len(j_idx))] if len(pos)
        else np.full((len(j_idx), 3), 0.5, np.float32)
    )  # fmt: skip
    scores = np.concatenate([cands.scores, j_scores])
    real = np.arange(len(idx)) < len(cands.image)
    order = draw_order(rng, len(idx), None if split.weights is None else split.weights[idx])
    net.train()
    sums: dict[str, float] = {}
    n = 0
    for s in range(0, len(order), batch_size):
        b = order[s : s + batch_size]
        x, geom, lab, off, w = make_batch(
            split.images, idx[b], quads[b], targets[b], scores[b], cfg, rng
        )
        terms = loss_terms(net(x, geom), lab, off, torch.from_numpy(real[b]), w)
        opt.zero_grad(set_to_none=True)
        terms["loss"].backward()
        opt.step()
        sched.step()
        for k, v in terms.items():
            sums[k] = sums.get(k, 0.0) + float(v.detach())
        n += 1
        if on_step is not None:
            on_step(sums["loss"] / n)
    return {k: v / max(n, 1) for k, v in sums.items()}


@dataclass(frozen=True)
class RefineTrainConfig:
    """Settings of one refiner training run (recorded in ``detector.json``)."""

    epochs: int = 12
    """Passes over the candidates (plus as many freshly jittered labelled gates)."""
    seed: int = 0
    """Seed of the initial weights, the shuffling and the augmentation."""
    batch_size: int = 256
    """Examples per optimisation step."""
    lr: float = 2e-3
    """Peak learning rate of AdamW (100 warm-up steps, then cosine decay to 0)."""
    weight_decay: float = 1e-4
    """AdamW weight decay."""
    limit: int | None = None
    """Use only the first ``limit`` images of each split (quick runs and tests)."""
    min_gate_px: float = 20.0
    """Smallest gate counted in the validation metrics, pixels."""
    tune: bool = True
    """After training, choose on the val split what :func:`tune` chooses (threshold, snap
    radius, squareness check, mirroring, passes, the corner network's input size)."""
    candidate_scale: float = 1.0
    """The corner network reads the frames whose candidates are trained and validated on at
    this fraction of the camera's size (as the detector does when tuned to a smaller input)."""
    candidate_iou: float = 0.5
    """Those candidates are de-duplicated at this overlap (as the detector does at
    ``RefineConfig.candidate_iou``)."""
    images_on_disk: bool = False
    """Keep the training images in ``OUT/train-images.npy``, mapped from disk, instead of in
    memory (they take 230 kB each at 320x240: 100,000 images need 23 GB, on disk then)."""


@dataclass(frozen=True)
class RefineResult:
    """What :func:`train_refiner` produced."""

    out_dir: Path
    best_epoch: int
    best_metrics: dict
    history: list[dict]


def train_refiner(
    detector: str | Path,
    data_dir: str | Path | list,
    out_dir: str | Path,
    epochs: int = 12,
    seed: int = 0,
    resume: bool = False,
    config: RefineTrainConfig | None = None,
    refine_config: RefineConfig | None = None,
    progress: bool = True,
    log: Callable[[str], None] | None = None,
    val_data: list[str | Path] | None = None,
    init: str | Path | None = None,
) -> RefineResult:
    """Train (or resume training) the second stage of a trained corner network.

    Output folder: ``best/`` and ``last/`` are complete detector checkpoints (the corner network
    copied, its decoding set to :data:`CANDIDATES`, plus the refiner); ``last/`` also holds
    ``refine_state.pt`` (what ``resume`` reads); ``candidates.npz`` (the training split's
    candidates: a resumed run, or a new one whose folder holds them, reads them instead of
    running the corner network over every training image again, unless the data or the network
    differ); ``refiner.onnx`` (best),
    ``history.json`` and TensorBoard logs in ``tb/``. Ctrl-C saves ``last/``; every epoch's
    shuffle and augmentation depend on (seed, epoch) alone, so a resumed run trains as one never
    interrupted.

    Args:
        detector: a trained first stage (checkpoint folder or file); its own refiner, if any,
            is ignored.
        data_dir: gen-dataset output, ideally generated with a seed the first stage was not
            trained on (its candidates' errors are then those of unseen images): its ``train``
            split is trained on, its ``val`` split validates and tunes. Several: the train
            splits of all are trained on, the first one's val split validates (unless
            ``val_data``); each a path or (path, share): each dataset's share of the training
            draws (examples drawn with replacement, each by its image's share / that dataset's
            images; without shares every example once an epoch). A COCO-keypoints folder of
            labelled real images at the camera's size (``import-gates``) joins training.
        out_dir: output folder.
        epochs: total epochs (a resumed run continues to this number).
        seed: seed of weights, shuffling and augmentation.
        resume: continue from ``OUT/last`` with the run's own settings.
        config: further settings of a new run (``epochs`` and ``seed`` take precedence).
        refine_config: architecture of a new refiner.
        progress: show a rich progress bar.
        log: called with one line per epoch.
        val_data: datasets whose val splits, together, validate every epoch and tune (default:
            the first of ``data_dir``). A bigger val set makes both choices less noisy; a
            finished run resumed with other ``val_data`` is tuned again on them.
        init: a checkpoint whose refiner a new run starts from (fine-tuning, for example on new
            data with a lower ``config.lr``); its architecture replaces ``refine_config``.

    Raises:
        FileNotFoundError / ValueError: bad detector or dataset, or OUT/last present without
            ``resume`` (or missing with it).
    """
    from icarus_vision.gate_detect.cnn import fuse_batchnorm
    from icarus_vision.gate_detect.cnn.checkpoint import (
        export_refiner_onnx,
        load_checkpoint,
        load_refiner,
        save_checkpoint,
    )
    from icarus_vision.gate_detect.cnn.data import load_splits
    from icarus_vision.gate_detect.cnn.train import (
        load_state,
        run_folders,
        save_state,
        sources_and_shares,
        warmup_cosine,
    )
    from icarus_vision.gate_detect.cnn.tune import score as _score

    cfg = replace(config or RefineTrainConfig(), epochs=epochs, seed=seed)
    if cfg.epochs < 1:
        raise ValueError(f"epochs must be >= 1, got {cfg.epochs}")
    if not 0.0 < cfg.candidate_scale <= 1.0 or not 0.0 < cfg.candidate_iou <= 1.0:
        raise ValueError(f"candidate_scale and candidate_iou must be in (0, 1]: {cfg}")
    out = Path(out_dir)
    last_dir, best_dir = run_folders(out, resume, STATE)
    corner_net, _, meta = load_checkpoint(last_dir if resume else detector)
    torch.manual_seed(cfg.seed)
    net = RefineNet(refine_config or RefineConfig())
    if init is not None and not resume:
        _, _, init_meta = load_checkpoint(init)
        net = load_refiner(init, init_meta)
        if net is None:
            raise ValueError(f"{init}: no refiner to start from")
        net.train()
    if resume:
        net = load_refiner(last_dir, meta)
        stored = meta.get("refine_training", {}).get("config", {})
        known = {f.name for f in fields(RefineTrainConfig)}
        cfg = replace(
            RefineTrainConfig(**{k: v for k, v in stored.items() if k in known}), epochs=epochs
        )
    first = fuse_batchnorm(copy.deepcopy(corner_net).eval())
    size = tuple(corner_net.cfg.image_size)
    dirs, shares = sources_and_shares(data_dir)
    # a finished run resumed is only tuned again: no training data needed
    finished = resume and meta.get("refine_training", {}).get("epoch", 0) >= cfg.epochs
    disk = out / TRAIN_IMAGES if cfg.images_on_disk else None
    train = None if finished else load_splits(dirs, "train", size, cfg.limit, disk, shares)
    val_dirs = list(val_data) if val_data else dirs[:1]
    val = load_splits(val_dirs, "val", size, cfg.limit)
    if log is not None:
        log("a finished run: tuning it again ..." if finished else
            f"first-stage candidates of {len(train.files)} + {len(val.files)} images ...")  # fmt: skip
    # trained and validated every epoch on the candidates of CANDIDATES (de-duplicated at
    # cfg.candidate_iou, the corner network reading frames at cfg.candidate_scale); tuned at
    # the end on those the detector will read (tune)
    cands, val_cands = None, None
    if not finished:
        read_at = input_sizes(size, (cfg.candidate_scale,))[0]
        read_at = None if read_at == size else read_at
        cand_cfg = replace(CANDIDATES, nms_iou=cfg.candidate_iou)
        key = {"data": [str(d) for d in dirs], "images": len(train.files), "limit": cfg.limit,
               "datasets": [dataset_digest(d) for d in dirs], "read_at": read_at,
               "decode": asdict(cand_cfg), "corner_network": weights_digest(corner_net)}  # fmt: skip
        # read by a resumed run, and by a new one in a folder holding those of the same key
        cands = load_candidates(out / CANDIDATE_CACHE, key)
        if cands is None:
            cands = collect(first, train, cand_cfg, read_at)
            save_candidates(out / CANDIDATE_CACHE, cands, key)
        elif log is not None:
            log(f"training candidates read from {out / CANDIDATE_CACHE}")
        val_cands = collect(first, val, cand_cfg, read_at)
    rcfg = replace(net.cfg, threshold=RefineConfig.threshold, snap=0.0)  # tuned at the end
    opt = torch.optim.AdamW(net.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
    steps_per_epoch = 1
    if not finished:
        n_jitter = len(jittered_truth(train, np.random.default_rng(0))[0])
        steps_per_epoch = int(np.ceil((len(cands.image) + n_jitter) / cfg.batch_size))
    sched = warmup_cosine(opt, cfg.epochs * steps_per_epoch)
    start, history, best = 0, [], (-1.0, -1, {})
    if resume:
        start, history, best, _ = load_state(last_dir / STATE, opt, sched)
    info = {"detector": str(detector), "data": [str(d) for d in dirs],
            "val_data": [str(d) for d in val_dirs], "config": asdict(cfg)}  # fmt: skip
    if shares is not None:
        info["shares"] = shares
    if resume and "init" in meta.get("refine_training", {}):
        info["init"] = meta["refine_training"]["init"]
    elif init is not None:
        info["init"] = str(init)
    first_info = meta.get("training", {})

    def save(folder: Path, epoch: int, extra: dict | None = None) -> None:
        save_checkpoint(folder, corner_net, CANDIDATES, first_info, net,
                        {**info, "epoch": epoch, **(extra or {})})  # fmt: skip

    def save_last(epoch: int, best: tuple) -> None:
        save(last_dir, epoch)
        save_state(last_dir / STATE, opt, sched, epoch, history, best)

    def one_epoch(epoch: int, rng: np.random.Generator, step) -> tuple[dict, dict, float]:
        losses = train_epoch(net, opt, sched, train, cands, rcfg, rng, cfg.batch_size, step)
        metrics = evaluate(net, val, val_cands.per_image, rcfg, cfg.min_gate_px)
        return losses, metrics, _score(metrics)

    best = run_epochs(
        out, start, cfg.epochs, cfg.seed, steps_per_epoch, one_epoch,
        lambda epoch, metrics: save(best_dir, epoch, {"val": metrics}), save_last, history, best,
        "refine", progress, log,
    )  # fmt: skip
    _, _, best_meta = load_checkpoint(best_dir)
    best_net = load_refiner(best_dir, best_meta)
    if cfg.tune:
        cand_cfg = replace(CANDIDATES, nms_iou=best_net.cfg.candidate_iou)
        per_size = {s: first_stage(first, val.images, cand_cfg, input_size=s)
                    for s in input_sizes(size)}  # fmt: skip
        tuned, input_size, metrics = tune(best_net, val, per_size, best_net.cfg, cfg.min_gate_px)
        best_net = RefineNet(tuned)
        best_net.load_state_dict(load_refiner(best_dir, best_meta).state_dict())
        net = best_net.eval()  # what save() writes
        corner_net.cfg = replace(corner_net.cfg, input_size=input_size)
        done = best_meta["refine_training"]  # a finished run resumed is only tuned again
        untuned = done.get("val_untuned", done.get("val"))
        save(best_dir, done["epoch"], {"val": metrics, "val_untuned": untuned})
        best = (best[0], best[1], metrics)
        if log is not None:
            log(f"tuned on val: corner network input {input_size[0]}x{input_size[1]}; {tuned}")
    export_refiner_onnx(best_net, out / REFINER_ONNX)
    return RefineResult(out, best[1], best[2], history)
