"""`icarus-vision eval-estimator`: fly a track with camera, detector and estimator; report the error."""

from __future__ import annotations

from datetime import datetime
from pathlib import Path

import typer
from rich.markup import escape
from rich.table import Table

from icarus_vision.cli import app, console, user_errors


def _fmt(x) -> str:
    return "-" if x is None else f"{x:.3f}"


@app.command("eval-estimator")
@user_errors
def eval_estimator_cmd(
    track: str = typer.Option("ten-gates", help="Built-in track name or a track TOML path."),
    detector: str = typer.Option("oracle", help="Detector: oracle, opencv or cnn[:PATH]."),
    seed: int = typer.Option(0, help="Random seed (env, odometry noise, map error, oracle noise)."),
    mode: str = typer.Option("map-aided", help="Estimator mode: map-aided or map-free."),
    pixel_noise: float = typer.Option(
        0.0, min=0.0, help="Oracle only: corner noise sigma, pixels."
    ),
    map_error: float = typer.Option(
        0.3, min=0.0, help="Map-aided: sigma of the prior map's gate displacement, m."
    ),
    json_path: Path = typer.Option(None, "--json", help="Also write the report to this JSON file."),
    out: Path = typer.Option(
        None, help="Output folder (default: runs/eval-estimator-<timestamp>/)."
    ),
) -> None:
    """Fly a track in PyBullet with the scripted pilot, the camera, a detector and the estimator,
    and report the error of the estimated next-gate position against ground truth."""
    from icarus_vision.estimator.config import config_for_detector
    from icarus_vision.estimator.evaluate import evaluate_estimator
    from icarus_vision.fileio import atomic_write_json
    from icarus_vision.gate_detect.registry import parse_spec

    config = config_for_detector(parse_spec(detector)[0], mode)
    out = out or Path("runs") / f"eval-estimator-{datetime.now():%Y%m%d-%H%M%S}"
    from icarus_vision.fileio import check_output

    check_output(json_path)
    check_output(out, folder=True)
    report = evaluate_estimator(
        track,
        detector,
        seed,
        config=config,
        pixel_noise=pixel_noise,
        map_error_m=map_error,
        plot_path=out / "error_vs_distance.png",
    )
    atomic_write_json(out / "report.json", report)
    if json_path is not None:
        atomic_write_json(json_path, report)
    r = report
    table = Table(title=f"eval-estimator: {r['track']} · {r['detector']} · {r['mode']}")
    table.add_column("metric")
    table.add_column("value")
    rows = [
        ("frames", str(r["frames"])),
        ("detection rate", f"{r['detection_rate']:.3f}"),
        (
            "error median / p95 [m]",
            f"{_fmt(r['rel_gate_error_m']['median'])} / {_fmt(r['rel_gate_error_m']['p95'])}",
        ),
        (
            "within 5 m: median / p95 [m]",
            f"{_fmt(r['within_5m']['median'])} / {_fmt(r['within_5m']['p95'])}",
        ),
        ("estimator cost [ms/frame]", _fmt(r["ms_per_frame"])),
        ("gates", f"{r['gates_passed']}/{r['gates_total']}"),
    ]
    for k, v in rows:
        table.add_row(escape(k), escape(v))
    console.print(table)
    console.print(f"report and plot written to {out}/")
