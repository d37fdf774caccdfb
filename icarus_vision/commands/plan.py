"""`icarus-vision plan`: CasADi minimum-time trajectory through a track (the lap-time ceiling)."""

from __future__ import annotations

from pathlib import Path

import typer

from icarus_vision.cli import app, console, user_errors


@app.command("plan")
@user_errors
def plan_cmd(
    track: str = typer.Option(
        None, help="Built-in track name or a track TOML path (default: the default track)."
    ),
    quad: Path = typer.Option(None, help="Quadrotor TOML file (default: the built-in racer-500g)."),
    laps: int = typer.Option(None, min=1, help="Laps to plan (default: the track's own)."),
    json_path: Path = typer.Option(None, "--json", help="Write the summary to this JSON file."),
    out: Path = typer.Option(Path("runs/plans"), help="Folder of the plan cache, CSV and plot."),
    nodes_per_gate: int = typer.Option(20, min=4, help="Shooting nodes per gate segment."),
    no_cache: bool = typer.Option(
        False, "--no-cache", help="Solve again even when a cached plan exists."
    ),
) -> None:
    """Solve the minimum-time trajectory (IPOPT, multiple shooting) and the point-mass bound.

    Writes the trajectory (CSV), a plot (top view, altitude, speed and thrust against time) and a
    cache that `race` reads to report how close to optimal a race was.
    """
    from icarus_vision.fileio import check_output
    from icarus_vision.planning.command import format_summary, run_plan
    from icarus_vision.sim.builtin import resolve_track

    check_output(json_path)
    check_output(out, folder=True)
    trk = resolve_track(track)
    if laps is not None:
        trk = trk.with_laps(laps)
    with console.status(f"planning {trk.name} ({len(trk.gates)} gates x {trk.laps} lap(s))..."):
        summary = run_plan(trk, quad, json_path=json_path, out_dir=out, nodes_per_gate=nodes_per_gate,
                           use_cache=not no_cache)  # fmt: skip
    console.print(format_summary(summary), markup=False, highlight=False)
