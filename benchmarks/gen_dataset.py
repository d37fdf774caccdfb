"""Dataset generation throughput: labelled 320x240 images per second, and peak memory per worker.

Usage: ``python benchmarks/gen_dataset.py [--num-images N] [--workers N] [--runs N] [--recipe PATH]``.
Generates the gates-v1 dataset (rendered, labelled, sensor noise, PNG-encoded, checksummed and
written) ``--runs`` times into a temporary folder and prints one JSON line with the median figures:

* ``images_per_s``: images over the whole rendering phase, worker start-up included;
* ``steady_images_per_s``: images between the first and the last image written;
* ``worker_peak_rss_mb``: the largest peak resident memory of a worker process;
* ``cpu_ms_per_image``: CPU time (user + system) of this process and its workers per image;
* ``cpu_bound_images_per_s``: ``workers`` cores' worth of that: the rate on otherwise idle cores;
* ``load_avg_1min``: the machine's load before each run (the rates above are wall-clock rates).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import tempfile
import time
from pathlib import Path

from icarus_vision.dataset import generate_dataset

RECIPE = Path(__file__).resolve().parents[1] / "datasets" / "gates-v1.toml"


def _cpu_s() -> float:
    """User + system CPU seconds of this process and its finished children."""
    me, kids = (
        resource.getrusage(resource.RUSAGE_SELF),
        resource.getrusage(resource.RUSAGE_CHILDREN),
    )
    return me.ru_utime + me.ru_stime + kids.ru_utime + kids.ru_stime


def one_run(recipe: Path, num_images: int, workers: int, seed: int) -> dict:
    stamps: list[tuple[float, int]] = []
    load = os.getloadavg()[0]
    before = _cpu_s()
    with tempfile.TemporaryDirectory(prefix="icarus-bench-") as tmp:
        result = generate_dataset(
            recipe, Path(tmp) / "ds", num_images, workers, seed,
            progress=lambda done, total: stamps.append((time.perf_counter(), done)),
        )  # fmt: skip
    cpu_ms = 1e3 * (_cpu_s() - before) / num_images
    (t0, n0), (t1, n1) = stamps[1], stamps[-1]
    return {
        "images_per_s": result.images_per_s,
        "steady_images_per_s": (n1 - n0) / (t1 - t0),
        "worker_peak_rss_mb": max(result.worker_peak_rss_mb),
        "cpu_ms_per_image": cpu_ms,
        "cpu_bound_images_per_s": workers * 1e3 / cpu_ms,
        "load_avg_1min": load,
        "seconds": result.seconds,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--recipe", type=Path, default=RECIPE)
    ap.add_argument("--num-images", type=int, default=1000)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    runs = [
        one_run(args.recipe, args.num_images, args.workers, args.seed) for _ in range(args.runs)
    ]
    med = {k: round(statistics.median(r[k] for r in runs), 1) for k in runs[0]}
    print(json.dumps({
        "num_images": args.num_images, "workers": args.workers, "runs": args.runs,
        "cpus": os.cpu_count(), **med,
        "per_run_images_per_s": [round(r["images_per_s"], 1) for r in runs],
    }))  # fmt: skip


if __name__ == "__main__":
    main()
