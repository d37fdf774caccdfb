"""``generate_dataset``: render a labelled dataset in parallel worker processes, resumably.

Work is cut into shards (:mod:`icarus_vision.dataset.layout`); each worker process renders whole
shards with its own PyBullet client. Shards draw from their own random streams, so the output is
byte-identical for the same recipe and seed whatever the number of workers or the timing. Every
file is written atomically (temporary name, then rename); ``manifest.json`` is written last, so a
folder without it is incomplete, and re-running resumes it: intact shards are kept, missing,
truncated or corrupt ones are rendered again.
"""

from __future__ import annotations

import json
import multiprocessing as mp
import os
import queue
import resource
import signal
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import cv2

from icarus_vision import __version__
from icarus_vision.dataset.coco import split_json, summary_stats
from icarus_vision.dataset.contact_sheet import contact_sheet
from icarus_vision.dataset.folder import mark_incomplete, prepare_folder
from icarus_vision.dataset.layout import (
    ANNOTATIONS,
    CONTACT_SHEET,
    MANIFEST,
    SPLITS,
    ShardSpec,
    plan_shards,
    split_counts,
)
from icarus_vision.dataset.shard import (
    read_valid_shard,
    render_shard,
    write_image,
    write_record,
    write_shard,
)
from icarus_vision.fileio import atomic_write_bytes, atomic_write_json
from icarus_vision.ray_runtime import start_ray
from icarus_vision.render.recipe import Recipe, load_recipe
from icarus_vision.render.scene import RENDERERS

FORMAT = "icarus-vision-dataset/2"
"""Layout version recorded in ``config.json`` and ``manifest.json`` (2: gates seen from behind are
labelled too, so a folder of format 1 is never resumed into a mixed dataset)."""

ProgressFn = Callable[[int, int], None]
"""``progress(done_images, total_images)``; the first call counts the images found complete."""


@dataclass(frozen=True)
class GenerationResult:
    """What a call of :func:`generate_dataset` did.

    Attributes:
        out_dir: the dataset folder.
        manifest: the manifest written (``manifest.json``).
        generated: names of the shards rendered by this call.
        reused: names of the shards found complete and kept.
        seconds: wall time of the whole call, s.
        images_per_s: images rendered (labelled, encoded and written) per second of rendering.
        worker_peak_rss_mb: peak resident memory of each worker process, MiB (the calling process
            when ``workers`` is 1).
    """

    out_dir: Path
    manifest: dict
    generated: tuple[str, ...]
    reused: tuple[str, ...]
    seconds: float
    images_per_s: float
    worker_peak_rss_mb: tuple[float, ...]


def _peak_rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0  # Linux: KiB


_TICKS: mp.Queue | None = None


def _init_worker(ticks: mp.Queue, tmp_dir: str) -> None:
    """Worker set-up: report progress to ``ticks``; leave Ctrl-C to the parent (which terminates
    the pool); one OpenCV thread; temporary files (scene textures) under ``tmp_dir``, which the
    parent removes even when it had to kill the worker."""
    global _TICKS
    _TICKS = ticks
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    cv2.setNumThreads(1)
    tempfile.tempdir = tmp_dir


Job = tuple[Recipe, int, ShardSpec, Path, str]
"""One shard to render: recipe, seed, shard, output folder, renderer."""


def _write(job: Job, tick: Callable[[], None]) -> dict:
    recipe, seed, spec, out_dir, renderer = job
    return write_shard(recipe, seed, spec, out_dir, tick, renderer)


def _work(job: Job) -> tuple[dict, int, float]:
    record = _write(job, tick=lambda: _TICKS.put(1))
    return record, os.getpid(), _peak_rss_mb()


def _check_args(num_images: int, workers: int, seed: int, renderer: str) -> None:
    for name, value, low in (("num_images", num_images, 1), ("workers", workers, 1)):
        if isinstance(value, bool) or not isinstance(value, int) or value < low:
            raise ValueError(f"{name} must be an integer >= {low}, got {value!r}")
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise ValueError(f"seed must be an integer >= 0, got {seed!r}")
    if renderer not in RENDERERS:
        raise ValueError(f"renderer must be one of {', '.join(RENDERERS)}, got {renderer!r}")


def _render(
    jobs: list[Job], workers: int, done: int, total: int, progress: ProgressFn | None
) -> tuple[list[dict], dict[int, float]]:
    """Render the shards of ``jobs``; returns their records and the peak RSS per worker pid."""
    if workers == 1:
        records = []
        for job in jobs:

            def tick() -> None:
                nonlocal done
                done += 1
                if progress is not None:
                    progress(done, total)

            records.append(_write(job, tick))
        return records, {os.getpid(): _peak_rss_mb()}
    main_file = getattr(sys.modules["__main__"], "__file__", None)
    if main_file is not None and not os.path.exists(main_file):  # e.g. a script read from stdin
        raise RuntimeError(
            f"worker processes cannot start from a main module that is not a file ({main_file}); "
            "use workers=1 or run from a script file"
        )
    ctx = mp.get_context("spawn")
    ticks = ctx.Queue()
    records, rss = [], {}
    with (
        tempfile.TemporaryDirectory(prefix="icarus-gen-") as tmp_dir,
        ctx.Pool(min(workers, len(jobs)), _init_worker, (ticks, tmp_dir)) as pool,
    ):
        pending = [pool.apply_async(_work, (job,)) for job in jobs]
        while pending:
            try:
                done += ticks.get(timeout=0.1)
                if progress is not None:
                    progress(min(done, total), total)
            except queue.Empty:
                pass
            for res in [r for r in pending if r.ready()]:
                record, pid, mb = res.get()  # re-raises a worker's exception
                records.append(record)
                rss[pid] = max(rss.get(pid, 0.0), mb)
                pending.remove(res)
    if progress is not None:  # ticks still in flight when the last shard finished
        progress(total, total)
    return records, rss


def _ray_shard(job: Job) -> tuple[list[tuple[str, bytes]], dict, int, float]:
    """A Ray task: render one shard in memory; the caller writes it (no shared disk needed)."""
    recipe, seed, spec, _, renderer = job
    cv2.setNumThreads(1)
    files: list[tuple[str, bytes]] = []
    record = render_shard(recipe, seed, spec, lambda name, png: files.append((name, png)), renderer)
    return files, record, os.getpid(), _peak_rss_mb()


def _render_ray(
    jobs: list[Job], done: int, total: int, progress: ProgressFn | None
) -> tuple[list[dict], dict[int, float]]:
    """Render the shards of ``jobs`` as Ray tasks (one core each) and write them here, each
    shard's images first and its record last, as the local workers do."""
    import ray

    task = ray.remote(num_cpus=1)(_ray_shard)
    pending = {task.remote(job): job for job in jobs}
    records, rss = [], {}
    try:
        while pending:
            ready, _ = ray.wait(list(pending), num_returns=1)
            job = pending.pop(ready[0])
            files, record, pid, mb = ray.get(ready[0])  # re-raises a task's exception
            out_dir, spec = job[3], job[2]
            for name, png in files:
                write_image(out_dir, name, png)
            records.append(write_record(out_dir, spec, record))
            rss[pid] = max(rss.get(pid, 0.0), mb)
            done += spec.count
            if progress is not None:
                progress(min(done, total), total)
    finally:
        for ref in pending:  # Ctrl-C or a failed shard: the rest is not needed
            ray.cancel(ref, force=True)
    return records, rss


def generate_dataset(
    recipe_path: str | os.PathLike,
    out_dir: str | os.PathLike,
    num_images: int,
    workers: int = 2,
    seed: int = 0,
    force: bool = False,
    progress: ProgressFn | None = None,
    renderer: str = "tiny",
    ray: bool = False,
    address: str | None = None,
) -> GenerationResult:
    """Generate (or resume) a labelled gate-keypoint dataset.

    Args:
        recipe_path: recipe TOML (``datasets/gates-v1.toml``): randomisation ranges, poses, layout.
        out_dir: output folder; created if missing. See :mod:`icarus_vision.dataset.layout`.
        num_images: number of images over all splits, >= 1.
        workers: worker processes (1: render in this process).
        seed: base seed, >= 0.
        force: overwrite a folder holding a different dataset (or other files).
        progress: called with (done_images, total_images) as images are written.
        renderer: ``"tiny"`` (TinyRenderer, CPU) or ``"egl"`` (PyBullet's EGL plugin: OpenGL on
            the GPU, or Mesa's software renderer); recorded in ``manifest.json`` and, when not
            tiny, in ``config.json``: a folder never mixes renderers.
        ray: render the shards as Ray tasks (``workers`` is then unused: Ray runs one per core
            of this machine or of the cluster at ``address``); the same files as without.
        address: with ``ray``, a Ray cluster's address (None: start Ray here).

    Returns:
        a :class:`GenerationResult`.

    Raises:
        ValueError: bad arguments, a missing or malformed recipe (naming the key), or an output
            folder holding something else without ``force``.
        RuntimeError: the renderer cannot run here (EGL: the plugin does not load).
    """
    t0 = time.perf_counter()
    _check_args(num_images, workers, seed, renderer)
    recipe = load_recipe(recipe_path)
    out = Path(out_dir)
    identity = {
        "format": FORMAT,
        "version": __version__,
        "seed": seed,
        "num_images": num_images,
        "recipe": recipe.to_dict(),
    }
    if renderer != "tiny":
        # Renderers draw slightly different pixels, so a folder never mixes them; TinyRenderer
        # datasets keep the identity they always had, and stay resumable.
        identity["renderer"] = renderer
    identity = json.loads(json.dumps(identity))  # as read back from config.json (lists, not tuples)
    try:
        prepare_folder(out, identity, force)
    except OSError as e:
        raise ValueError(f"{out}: cannot use as output folder ({e.strerror or e})") from None
    specs = plan_shards(num_images, recipe.dataset)
    found = {s.name: read_valid_shard(out, s) for s in specs}
    todo = [s for s in specs if found[s.name] is None]
    reused = [s for s in specs if found[s.name] is not None]
    done = sum(s.count for s in reused)
    if progress is not None:
        progress(done, num_images)
    rss: dict[int, float] = {}
    t_render = time.perf_counter()
    if todo:
        mark_incomplete(out)
        jobs = [(recipe, seed, s, out, renderer) for s in todo]
        if ray:
            start_ray(address)
            t_render = time.perf_counter()  # Ray's start-up is not rendering
            records, rss = _render_ray(jobs, done, num_images, progress)
        else:
            records, rss = _render(jobs, workers, done, num_images, progress)
        found.update({r["name"]: r for r in records})
    render_s = time.perf_counter() - t_render
    shard_records = [found[s.name] for s in specs]
    manifest = _finish(out, recipe, seed, num_images, renderer, specs, shard_records)
    rendered = sum(s.count for s in todo)
    return GenerationResult(
        out_dir=out,
        manifest=manifest,
        generated=tuple(s.name for s in todo),
        reused=tuple(s.name for s in reused),
        seconds=time.perf_counter() - t0,
        images_per_s=rendered / render_s if rendered else 0.0,
        worker_peak_rss_mb=tuple(round(v, 1) for v in rss.values()),
    )


def _finish(
    out: Path,
    recipe: Recipe,
    seed: int,
    num_images: int,
    renderer: str,
    specs: list[ShardSpec],
    records,
) -> dict:
    """Write the split annotation files, the contact sheet and, last, the manifest."""
    info = {"recipe": recipe.name, "seed": seed, "version": __version__}
    ann_id = 1
    for split in SPLITS:
        coco = split_json([r for r in records if r["split"] == split], split, info, ann_id)
        ann_id += len(coco["annotations"])
        text = json.dumps(coco, separators=(",", ":"), allow_nan=False)
        atomic_write_bytes(out / ANNOTATIONS / f"{split}.json", text.encode())
    images = [im for r in records for im in r["images"]]
    anns = [a for r in records for a in r["annotations"]]
    atomic_write_bytes(out / CONTACT_SHEET, contact_sheet(out, images, anns))
    manifest = {
        "format": FORMAT,
        "name": recipe.name,
        "version": __version__,
        "seed": seed,
        "num_images": num_images,
        "image_size": [recipe.dataset.width, recipe.dataset.height],
        "renderer": renderer,
        "splits": split_counts(num_images, recipe.dataset.splits),
        "annotations": {s: f"{ANNOTATIONS}/{s}.json" for s in SPLITS},
        "contact_sheet": CONTACT_SHEET,
        "recipe": recipe.to_dict(),
        "shards": [
            {
                "name": s.name,
                "split": s.split,
                "first_id": s.first_id,
                "count": s.count,
                "checksum": r["checksum"],
            }
            for s, r in zip(specs, records, strict=True)
        ],  # fmt: skip
        "stats": summary_stats(records),
    }
    atomic_write_json(out / MANIFEST, manifest)
    return json.loads(json.dumps(manifest))  # as read back from the file
