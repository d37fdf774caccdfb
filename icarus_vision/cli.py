"""The ``icarus-vision`` command line. Thin: parse, call one library function, print.

User errors (bad files, names, values) print one line to stderr and exit 1, without a traceback.
"""

from __future__ import annotations

import functools
import sys
from datetime import datetime
from pathlib import Path

import typer
from rich.console import Console
from rich.markup import escape
from rich.table import Table

app = typer.Typer(
    help="icarus-vision: vision-based autonomous drone racing.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)
console = Console()
err_console = Console(stderr=True)


def user_errors(fn):
    """Turn the library's user-facing exceptions into a one-line error and exit code 1."""

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        try:
            return fn(*args, **kwargs)
        except (ValueError, FileNotFoundError, RuntimeError) as e:
            err_console.print(
                f"[bold red]error:[/] {e}", markup=True, highlight=False, soft_wrap=True
            )
            raise typer.Exit(1) from None
        except KeyboardInterrupt:
            err_console.print("interrupted")
            sys.exit(130)

    return wrapper


@app.command("tracks")
@user_errors
def tracks_cmd() -> None:
    """List the built-in tracks."""
    from icarus_vision.sim.builtin import BUILTIN_TRACKS, DEFAULT_TRACK, builtin_track

    table = Table(title="built-in tracks")
    for col in ("name", "gates", "laps", "length [m]", "height [m]"):
        table.add_column(col)
    import numpy as np

    for name in BUILTIN_TRACKS:
        t = builtin_track(name)
        pts = np.array([t.start_pos, *(g.pos for g in t.gates)])
        length = float(np.linalg.norm(np.diff(pts, axis=0), axis=1).sum())
        z = pts[1:, 2]
        label = f"{name} (default)" if name == DEFAULT_TRACK else name
        table.add_row(
            label, str(len(t.gates)), str(t.laps), f"{length:.1f}", f"{z.min():.1f}–{z.max():.1f}"
        )
    console.print(table)


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


def main() -> None:
    app()


if __name__ == "__main__":
    main()
