"""`icarus-vision race`: fly a race headless, with report and plot."""

from __future__ import annotations

from datetime import datetime
from pathlib import Path

import typer
from rich.markup import escape
from rich.table import Table

from icarus_vision.cli import app, console, user_errors


@app.command("race")
@user_errors
def race_cmd(
    track: str = typer.Option(
        None, help="Built-in track name or a track TOML path (default: the default track)."
    ),
    quad: Path = typer.Option(None, help="Quadrotor TOML file (default: the built-in racer-500g)."),
    laps: int = typer.Option(None, min=1, help="Laps to fly (default: the track's own)."),
    seed: int = typer.Option(0, help="Random seed."),
    backend: str = typer.Option("pybullet", help="Physics backend: pybullet or batched."),
    randomize: bool = typer.Option(
        False, "--randomize/--no-randomize", help="Randomise mass, wind and gates."
    ),
    json_path: Path = typer.Option(None, "--json", help="Also write the report to this JSON file."),
    out: Path = typer.Option(None, help="Output folder (default: runs/race-<timestamp>/)."),
) -> None:
    """Fly a race headless and write its report and trajectory plot.

    The pilot is currently the scripted geometric controller on ground-truth observations.
    """
    from icarus_vision.fileio import atomic_write_json
    from icarus_vision.racing.plots import plot_trajectory
    from icarus_vision.racing.runner import run_race
    from icarus_vision.sim.quad import load_quad

    if backend not in ("pybullet", "batched"):
        raise ValueError(f"unknown backend {backend!r}; choose pybullet or batched")
    quad_params = load_quad(quad) if quad is not None else None
    result = run_race(
        track, quad=quad_params, laps=laps, seed=seed, backend=backend, randomize=randomize
    )
    out = out or Path("runs") / f"race-{datetime.now():%Y%m%d-%H%M%S}"
    out.mkdir(parents=True, exist_ok=True)
    r = result.report
    atomic_write_json(out / "report.json", r)
    if json_path is not None:
        atomic_write_json(json_path, r)
    crash = result.pos[-1] if r["crashed"] else None
    plot_trajectory(
        out / "trajectory.png",
        result.track,
        result.t,
        result.pos,
        result.speed,
        crash,
        title=f"{r['track']} ({r['policy']})",
    )
    table = Table(title=f"race: {r['track']} · {r['policy']} · {r['backend']}")
    table.add_column("metric")
    table.add_column("value")
    rows = [
        ("gates", f"{r['gates_passed']}/{r['gates_total']}"),
        ("finished", str(r["finished"])),
        ("crash", r["crash_reason"] or "-"),
        ("lap times [s]", ", ".join(f"{x:.2f}" for x in r["lap_times_s"]) or "-"),
        ("max / mean speed [m/s]", f"{r['max_speed_mps']:.1f} / {r['mean_speed_mps']:.1f}"),
        ("real-time factor", f"{r['realtime_factor']:.1f}x"),
    ]
    for k, v in rows:
        table.add_row(escape(k), escape(v))
    console.print(table)
    console.print(f"report and plot written to {out}/")
