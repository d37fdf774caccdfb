"""`icarus-vision gen-dataset`: render a labelled gate-keypoint dataset (PNG + COCO keypoints)."""

from __future__ import annotations

from contextlib import ExitStack
from pathlib import Path

import typer
from rich.markup import escape
from rich.progress import (
    BarColumn,
    MofNCompleteColumn,
    ProgressColumn,
    TextColumn,
    TimeElapsedColumn,
    TimeRemainingColumn,
)
from rich.text import Text

from icarus_vision.cli import app, console, progress_reporter, user_errors


class _ImagesPerSecond(ProgressColumn):
    """Rendering speed in images per second."""

    def render(self, task) -> Text:
        speed = task.speed
        return Text(f"{speed:6.1f} img/s" if speed else "     - img/s", style="progress.data.speed")


@app.command("gen-dataset")
@user_errors
def gen_dataset_cmd(
    recipe: Path = typer.Option(..., help="Dataset recipe TOML, e.g. datasets/gates-v1.toml."),
    out: Path = typer.Option(..., help="Output folder (created; an interrupted run is resumed)."),
    num_images: int = typer.Option(1000, help="Number of images over all splits."),
    workers: int = typer.Option(2, help="Worker processes, one PyBullet client each."),
    seed: int = typer.Option(0, help="Random seed."),
    force: bool = typer.Option(False, help="Overwrite a folder holding a different dataset."),
    renderer: str = typer.Option(
        "tiny",
        help="tiny (PyBullet's TinyRenderer, CPU) or egl (its EGL plugin: OpenGL on the GPU, or "
        "Mesa's software renderer without one).",
    ),
    ray: bool = typer.Option(
        False,
        "--ray",
        help="Render the shards as Ray tasks: on this machine's cores, or on a cluster with "
        "--address (the same files either way; --workers is then unused).",
    ),
    address: str = typer.Option(
        None, help="With --ray: a Ray cluster's address (`ray start --head` prints it)."
    ),
) -> None:
    """Render racing-like FPV frames with labelled gate corners.

    Writes images/ (PNG), annotations/{train,val,test}.json (COCO keypoints TL, TR, BR, BL),
    manifest.json and contact_sheet.png. The same recipe and seed give identical files; re-running
    resumes an interrupted run, keeping the shards that are complete and intact.
    """
    from icarus_vision.dataset import generate_dataset

    if address is not None and not ray:
        raise ValueError("--address needs --ray")
    columns = (
        TextColumn("[bold]gen-dataset"),
        BarColumn(),
        MofNCompleteColumn(),
        _ImagesPerSecond(),
        TimeElapsedColumn(),
        TimeRemainingColumn(),
    )
    with ExitStack() as stack:
        # started on the first report; the images found complete count from the start, not
        # towards the speed
        progress = progress_reporter(stack, columns)
        result = generate_dataset(
            recipe, out, num_images, workers, seed, force, progress, renderer=renderer,
            ray=ray, address=address,
        )  # fmt: skip
    m = result.manifest
    stats = m["stats"]
    splits = ", ".join(f"{k} {v}" for k, v in m["splits"].items())
    console.print(
        f"{m['num_images']} images ({splits}), {stats['annotations']} gates, "
        f"{stats['images_without_gates']} frames without a gate; rendered "
        f"{len(result.generated)} shard(s), kept {len(result.reused)}"
        + (f", {result.images_per_s:.1f} images/s" if result.generated else ""),
        highlight=False,
    )
    console.print(f"dataset written to {escape(str(result.out_dir))}/", highlight=False)
