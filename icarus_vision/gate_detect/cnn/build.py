"""``build-detector``: a CNN detector from nothing, in one resumable command.

A build file (TOML, e.g. ``configs/detector-build.toml``) lists the datasets to generate and the
stages to train, each stage starting from the checkpoint the one before it wrote:

.. code-block:: toml

    name = "detector"
    [[datasets]]                      # rendered first, in order (gen-dataset, resumable)
    name = "corner"                   # OUT/datasets/corner
    recipe = "gates-v3"               # a packaged recipe or a path
    images = 20000
    seed = 0
    [corner]                          # train-detector; data names datasets, "name:share" mixes
                                      # (so does the data of refiner, zoom and rescorer)
    data = ["corner"]
    epochs = 40
    init = "shipped"                  # optional: fine-tune the shipped network (corner, refiner)
    train = { ignore_below_px = 12 }  # TrainConfig fields; model = {...}: ModelConfig fields
    [refiner]                         # train-refiner on the corner network's candidates
    data = ["refine"]; val = ["refine"]; epochs = 10
    train = {...}; net = {...}        # RefineTrainConfig, RefineConfig fields
    [zoom]                            # train-zoom; val: one dataset
    [rescorer]                        # train-rescorer; splits = ["train"]
    [quantize]                        # int8 copies: data, images, split
    # keep = "shipped" (or a checkpoint) in [refiner], [zoom] and [rescorer]: those stages of that
    # detector on the new corner network, untrained (its input size and candidate decoding); a
    # kept rescorer may follow trained stages (it is put on the finished ones). keep in [corner]:
    # that detector's corner network, untrained, and the later stages trained on it
    [evaluate]                        # eval-detector on data's test split: OUT/eval.json and
                                      # OUT/detector/error_model.json

Every stage is optional except ``corner``; the thresholds are tuned on val by the stages
themselves. Output: ``OUT/datasets/``, one folder per stage, ``OUT/detector/`` (the finished
checkpoint, int8 copies included) and ``OUT/build.json`` (each step's time; a finished step is not
run again, an interrupted one resumes). ``--scale`` multiplies every dataset's images and every
stage's epochs (at least 1 each): a quick run of the same recipe.
"""

from __future__ import annotations

import hashlib
import json
import math
import shutil
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

from icarus_vision.dataset.layout import split_share
from icarus_vision.fileio import atomic_write_json, read_toml
from icarus_vision.validation import check_table, require_list, require_table

STAGES = ("corner", "refiner", "zoom", "rescorer", "quantize", "evaluate")
"""The build's steps after the datasets, in order."""
TRAINING = ("corner", "refiner", "zoom", "rescorer")
"""The stages whose ``data`` is training data: the ones that take shares (``name:share``)."""


@dataclass(frozen=True)
class DatasetSpec:
    """One dataset a build renders."""

    name: str
    recipe: str
    images: int
    seed: int = 0


@dataclass(frozen=True)
class StageSpec:
    """One stage: its data (dataset names, ``name:share`` for a training stage's: corner,
    refiner, zoom, rescorer), validation data, epochs and the settings of its configuration
    dataclasses."""

    data: tuple[str, ...] = ()
    val: tuple[str, ...] = ()
    epochs: int = 1
    init: str = ""
    keep: str = ""
    images: int = 400
    split: str = "val"
    splits: tuple[str, ...] = ("train",)
    train: dict = field(default_factory=dict)
    model: dict = field(default_factory=dict)
    net: dict = field(default_factory=dict)


@dataclass(frozen=True)
class BuildSpec:
    """A whole build file."""

    name: str
    datasets: tuple[DatasetSpec, ...]
    stages: dict[str, StageSpec]
    source: str = "<memory>"


def load_build(path: str | Path) -> BuildSpec:
    """Read and check a build file; ValueError names the file and the key."""
    raw = dict(read_toml(path, "build", ValueError))
    src = str(path)
    name = raw.pop("name", Path(path).stem)
    sets = []
    for i, d in enumerate(require_list(raw.pop("datasets", []), f"{src}: datasets", ValueError)):
        kw = check_table(DatasetSpec, d, f"{src}: datasets[{i}]", ValueError)
        if "name" not in kw or "recipe" not in kw or "images" not in kw:
            raise ValueError(f"{src}: datasets[{i}]: needs name, recipe and images")
        if kw["images"] < 1:
            raise ValueError(f"{src}: datasets[{i}].images: must be >= 1")
        sets.append(DatasetSpec(**kw))
    names = {d.name for d in sets}
    if len(names) != len(sets):
        raise ValueError(f"{src}: datasets: names must differ")
    unknown = sorted(set(raw) - set(STAGES))
    if unknown:
        raise ValueError(f"{src}: unknown table(s) {unknown}; allowed: {list(STAGES)}")
    if "corner" not in raw:
        raise ValueError(f"{src}: a build needs a [corner] stage")
    stages = {}
    for stage in STAGES:
        if stage not in raw:
            continue
        table = require_table(raw[stage], f"{src}: [{stage}]", ValueError)
        spec = StageSpec(**check_table(StageSpec, table, f"{src}: [{stage}]", ValueError))
        for key in ("data", "val"):
            for ref in getattr(spec, key):
                ref_name, share = split_share(ref)
                if share is not None and (key != "data" or stage not in TRAINING):
                    raise ValueError(
                        f"{src}: [{stage}].{key}: shares (name:share) are for the data of "
                        f"{', '.join(f'[{t}]' for t in TRAINING)} only"
                    )
                if ref_name not in names:
                    raise ValueError(
                        f"{src}: [{stage}].{key}: {ref!r} names no dataset of the build"
                    )
                if share is not None and not (0 < share < math.inf):
                    raise ValueError(f"{src}: [{stage}].{key}: {ref!r}: a share must be > 0")
        if spec.epochs < 1:
            raise ValueError(f"{src}: [{stage}].epochs: must be >= 1")
        if spec.keep and stage not in ("corner", "refiner", "zoom", "rescorer"):
            raise ValueError(
                f"{src}: [{stage}].keep: only a corner network, refiner, zoom or rescorer is kept"
            )
        if not spec.data and not spec.keep:
            raise ValueError(f"{src}: [{stage}].data: needs at least one dataset")
        stages[stage] = spec
    for later, needs in (("zoom", "refiner"), ("rescorer", "zoom")):
        if later in stages and needs not in stages:
            raise ValueError(f"{src}: [{later}] needs a [{needs}] stage before it")
    kept = [k for k in ("refiner", "zoom") if k in stages and stages[k].keep]
    sources = {stages[k].keep for k in stages if stages[k].keep}
    if len(sources) > 1 or kept != ["refiner", "zoom"][: len(kept)]:
        raise ValueError(
            f"{src}: keep: the kept stages come from one detector, and a kept zoom stage needs "
            "a kept refiner"
        )
    return BuildSpec(str(name), tuple(sets), stages, src)


def build_detector(
    spec: BuildSpec,
    out: str | Path,
    scale: float = 1.0,
    workers: int = 2,
    seed: int = 0,
    log: Callable[[str], None] = print,
    progress: bool = True,
) -> Path:
    """Run (or resume) a build (module docstring); returns ``OUT/detector``."""
    from icarus_vision.dataset import generate_dataset

    if not scale > 0:
        raise ValueError(f"scale must be > 0, got {scale}")
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    record_path = out / "build.json"
    record = json.loads(record_path.read_text()) if record_path.is_file() else {}
    settings = json.dumps([asdict(d) for d in spec.datasets] + [
        {k: asdict(v)} for k, v in spec.stages.items()], sort_keys=True, default=str)  # fmt: skip
    ident = {"name": spec.name, "source": spec.source, "scale": scale, "seed": seed,
             "settings": hashlib.sha256(settings.encode()).hexdigest()[:16]}  # fmt: skip
    if record.get("build", ident) != ident:
        raise ValueError(
            f"{out} holds another build, or this build file was changed since its steps ran "
            f"({record.get('build')}); choose another --out"
        )
    record["build"] = ident
    steps = record.setdefault("steps", {})

    # A step stopped part-way (Ctrl-C, SIGTERM, an error) keeps the time it ran, so a finished
    # step's seconds are its whole time over every session that worked on it.
    partial = record.setdefault("interrupted", {})

    def step(name: str, fn: Callable[[], None]) -> None:
        if name in steps:
            log(f"{name}: done before ({steps[name]['seconds']:.0f} s)")
            return
        before = partial.get(name, 0.0)
        log(f"{name}: running" + (f" (resumed after {before:.0f} s)" if before else ""))
        t0 = time.perf_counter()
        try:
            fn()
        except BaseException:
            partial[name] = round(before + time.perf_counter() - t0, 1)
            atomic_write_json(record_path, record)
            raise
        steps[name] = {"seconds": round(before + time.perf_counter() - t0, 1)}
        partial.pop(name, None)
        atomic_write_json(record_path, record)

    data = {d.name: out / "datasets" / d.name for d in spec.datasets}
    for d in spec.datasets:
        n = max(1, math.ceil(d.images * scale))
        step(f"dataset {d.name}", lambda d=d, n=n: generate_dataset(
            d.recipe, data[d.name], n, workers=workers, seed=d.seed))  # fmt: skip

    def epochs(s: StageSpec) -> int:
        return max(1, math.ceil(s.epochs * scale))

    def resumes(folder: Path) -> bool:
        return (folder / "last").is_dir()

    st = spec.stages
    current = out / "corner" / "best"
    source = next((_init(v.keep) for v in st.values() if v.keep), None)  # one (load_build)
    if st["corner"].keep:
        step("corner", lambda: corner_network(source, current))
    else:
        step("corner", lambda: _corner(st["corner"], data, out / "corner", epochs(st["corner"]),
                                       seed, resumes(out / "corner"), log, progress))  # fmt: skip
    kept = [k for k in ("refiner", "zoom") if k in st and st[k].keep]
    trained = [k for k in ("refiner", "zoom") if k in st and not st[k].keep]
    if "rescorer" in st and st["rescorer"].keep and not trained:
        kept.append("rescorer")  # on the kept stages: grafted with them
    if kept:  # the later stages of another detector on this corner network (no training)
        step("kept stages", lambda: graft(current, source, out / "kept", kept))
        current = out / "kept"
        st = {k: v for k, v in st.items() if k not in kept}
    if "refiner" in st:
        s = st["refiner"]
        step("refiner", lambda: _refiner(s, data, current, out / "refiner", epochs(s), seed,
                                         resumes(out / "refiner"), log, progress))  # fmt: skip
        current = out / "refiner" / "best"
    if "zoom" in st:
        s = st["zoom"]
        step("zoom", lambda: _zoom(s, data, current, out / "zoom", epochs(s), seed,
                                   resumes(out / "zoom"), log, progress))  # fmt: skip
        current = out / "zoom" / "best"
    if "rescorer" in st and st["rescorer"].keep:  # on the networks trained above
        step("kept rescorer", lambda: graft(current, source, out / "rescorer", ["rescorer"]))
        current = out / "rescorer"
    elif "rescorer" in st:
        s = st["rescorer"]
        step("rescorer", lambda: _rescorer(s, data, current, out / "rescorer", epochs(s), seed,
                                           log, progress))  # fmt: skip
        current = out / "rescorer"
    final = out / "detector"

    def finish() -> None:
        shutil.rmtree(final, ignore_errors=True)
        shutil.copytree(current, final, ignore=shutil.ignore_patterns("*.npz", "parts", "*.pt"))

    step("detector", finish)
    if "quantize" in st:
        from icarus_vision.gate_detect.cnn.quantize import quantize_detector

        s = st["quantize"]
        step("quantize", lambda: quantize_detector(final, [data[n] for n in s.data], final,
                                                   s.images, s.split, seed))  # fmt: skip
    if "evaluate" in st:
        from icarus_vision.gate_detect.evaluate import eval_detector

        s = st["evaluate"]
        step("evaluate", lambda: eval_detector(data[s.data[0]], f"cnn:{final}", out / "eval.json",
                                               final / "error_model.json", resamples=0))  # fmt: skip
    record["detector"] = str(final)
    atomic_write_json(record_path, record)
    return final


def corner_network(source: Path, out: Path) -> Path:
    """The checkpoint ``source``'s corner network alone (no later stage), written to ``out``."""
    from icarus_vision.gate_detect.cnn.checkpoint import load_checkpoint, save_checkpoint

    model, decode, meta = load_checkpoint(source)
    shutil.rmtree(out, ignore_errors=True)
    return save_checkpoint(
        out, model, decode, {**meta.get("training", {}), "kept_from": str(source)}
    )


def graft(corner: Path, source: Path, out: Path, stages: list[str]) -> Path:
    """``source``'s later ``stages`` (refiner, zoom, rescorer) on the checkpoint ``corner``,
    written to ``out``. With ``source``'s refiner, the corner network reads frames at
    ``source``'s input size with ``source``'s candidate decoding (what that refiner was tuned
    with); otherwise it keeps its own, and its own refiner and zoom stage stay where ``source``'s
    are not put in their place."""
    from icarus_vision.gate_detect.cnn.checkpoint import (
        load_checkpoint,
        load_refiner,
        load_rescorer,
        load_zoom,
        save_checkpoint,
        save_rescorer,
    )

    model, decode, meta = load_checkpoint(corner)
    shipped, source_decode, smeta = load_checkpoint(source)
    if "refiner" in stages:
        model.cfg = replace(model.cfg, input_size=shipped.cfg.input_size)
        decode = source_decode
    own = {"refiner": (corner, meta), "zoom": (corner, meta)}
    own.update({k: (source, smeta) for k in stages})
    refiner, zoom = load_refiner(*own["refiner"]), load_zoom(*own["zoom"])
    info = (
        {**meta.get("training", {}), "later_stages": str(source)}
        if stages
        else meta.get("training", {})
    )
    shutil.rmtree(out, ignore_errors=True)
    save_checkpoint(out, model, decode, info, refiner, own["refiner"][1].get("refine_training"),
                    zoom, own["zoom"][1].get("zoom_training"))  # fmt: skip
    if "rescorer" in stages:
        save_rescorer(out, load_rescorer(source, smeta), smeta.get("rescore_training", {}))
    return out


def _sources(refs, data: dict[str, Path]) -> list:
    out = []
    for ref in refs:
        name, share = split_share(ref)
        out.append(data[name] if share is None else (data[name], share))
    return out


def _corner(s: StageSpec, data, out: Path, epochs: int, seed: int, resume: bool, log, progress):
    from icarus_vision.gate_detect.cnn.model import ModelConfig
    from icarus_vision.gate_detect.cnn.train import TrainConfig, train_detector

    cfg = TrainConfig(**check_table(TrainConfig, s.train, "[corner].train", ValueError))
    model = ModelConfig(**check_table(ModelConfig, s.model, "[corner].model", ValueError))
    train_detector(_sources(s.data, data), out, epochs=epochs, seed=seed, resume=resume,
                   config=cfg, model_config=model, init=_init(s.init), log=log,
                   progress=progress)  # fmt: skip


def _refiner(s: StageSpec, data, detector: Path, out: Path, epochs: int, seed: int, resume: bool,
             log, progress):  # fmt: skip
    from icarus_vision.gate_detect.cnn.refine import RefineConfig
    from icarus_vision.gate_detect.cnn.refine_train import RefineTrainConfig, train_refiner

    cfg = RefineTrainConfig(
        **check_table(RefineTrainConfig, s.train, "[refiner].train", ValueError)
    )
    net = RefineConfig(**check_table(RefineConfig, s.net, "[refiner].net", ValueError))
    train_refiner(detector, _sources(s.data, data), out, epochs=epochs, seed=seed, resume=resume,
                  config=cfg, refine_config=net, log=log, progress=progress,
                  val_data=_sources(s.val, data) or None, init=_init(s.init))  # fmt: skip


def _init(spec: str):
    """A stage's ``init``: none (""), the shipped detector ("shipped") or a checkpoint path."""
    from icarus_vision.gate_detect.cnn.checkpoint import SHIPPED

    return {"": None, "shipped": SHIPPED}.get(spec, spec or None)


def _zoom(s: StageSpec, data, detector: Path, out: Path, epochs: int, seed: int, resume: bool,
          log, progress):  # fmt: skip
    from icarus_vision.gate_detect.cnn.zoom import ZoomConfig
    from icarus_vision.gate_detect.cnn.zoom_train import ZoomTrainConfig, train_zoom

    cfg = ZoomTrainConfig(**check_table(ZoomTrainConfig, s.train, "[zoom].train", ValueError))
    net = ZoomConfig(**check_table(ZoomConfig, s.net, "[zoom].net", ValueError))
    val = _sources(s.val, data)
    train_zoom(detector, _sources(s.data, data), out, val[0] if val else None, epochs=epochs,
               seed=seed, resume=resume, config=cfg, zoom_config=net, log=log,
               progress=progress)  # fmt: skip


def _rescorer(s: StageSpec, data, detector: Path, out: Path, epochs: int, seed: int, log,
              progress):  # fmt: skip
    from icarus_vision.gate_detect.cnn.rescore import RescoreConfig
    from icarus_vision.gate_detect.cnn.rescore_train import RescoreTrainConfig, train_rescorer

    cfg = RescoreTrainConfig(
        **check_table(RescoreTrainConfig, s.train, "[rescorer].train", ValueError)
    )
    cfg = replace(cfg, epochs=epochs, seed=seed)
    net = RescoreConfig(**check_table(RescoreConfig, s.net, "[rescorer].net", ValueError))
    train_rescorer(detector, _sources(s.data, data), out, list(s.splits), net, cfg,
                   progress=progress, log=log)  # fmt: skip


__all__ = ["BuildSpec", "build_detector", "load_build"]
