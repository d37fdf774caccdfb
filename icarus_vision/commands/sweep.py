"""`icarus-vision sweep`: train-policy trials on Ray Tune, proposed by Optuna, early-stopped by ASHA."""

from __future__ import annotations

from pathlib import Path

import typer
from rich.live import Live
from rich.markup import escape
from rich.table import Table

from icarus_vision.cli import app, console, user_errors


def _view(state, total: int) -> Table:
    best = state.best()
    counts = ", ".join(
        f"{state.count(s)} {s}" for s in ("running", "done", "stopped early", "failed")
    )
    title = f"sweep: {len(state.trials)} of {total} trials started ({counts})"
    if best is not None:
        title += f"; best {best['objective']:.3f} ({best['id']})"
    table = Table(title=title, title_justify="left")
    for col in ("trial", "status", "objective", "success", "stage", "steps", "min"):
        table.add_column(col, justify="right" if col not in ("trial", "status") else "left")
    for t in list(state.trials.values())[-12:]:
        obj = t.get("objective")
        table.add_row(
            t["id"], t["status"], "-" if obj is None else f"{obj:.3f}",
            "-" if t.get("success") is None else f"{t['success']:.2f}",
            str(t.get("stage", "-")), f"{t.get('timesteps') or 0:,}",
            "-" if t.get("minutes") is None else f"{t['minutes']:.1f}",
        )  # fmt: skip
    return table


@app.command("sweep")
@user_errors
def sweep_cmd(
    space: Path = typer.Option(
        None,
        help="Search-space TOML: [base] train-policy config, [search] distributions of its keys, "
        "[objective], optional [[start]] points (configs/sweep-ppo.toml). Not needed with --resume.",
    ),
    trials: int = typer.Option(8, min=1, help="Trials in all."),
    trial_minutes: float = typer.Option(10.0, min=0.01, help="Training wall-clock per trial."),
    reports: int = typer.Option(
        6, min=1, help="Objective evaluations per trial (where ASHA may stop it)."
    ),
    out: Path = typer.Option(..., help="Sweep folder (a folder holding anything is refused)."),
    address: str = typer.Option(
        None,
        help="Join a Ray cluster at this address (`ray start --head` prints it); default: Ray "
        "starts on this machine, one trial per core.",
    ),
    resume: bool = typer.Option(
        False, "--resume", help="Continue the sweep in --out; finished trials are not rerun."
    ),
    seed: int = typer.Option(0, help="Optuna's sampler seed and each trial's training seed."),
) -> None:
    """Sweep train-policy settings: Ray Tune runs the trials, Optuna's TPE proposes them, ASHA ends
    the ones that fall behind.

    Each trial is a normal train-policy run in OUT/trials/ID/ (TensorBoard logs, checkpoints,
    exported policy). OUT/results.csv has one row per trial, OUT/best.toml is the best trial's
    config (train-policy --config accepts it), objective.png and importance.png show the sweep.
    Ctrl-C stops it; --resume continues it.
    """
    from icarus_vision.policy.sweep import run_sweep

    if not resume and space is None:
        raise ValueError("--space is required (leave it out only with --resume)")
    with Live(console=console, refresh_per_second=2, transient=False) as live:
        live.update(f"starting Ray{' at ' + escape(address) if address else ''} ...")
        state = run_sweep(
            space, out, trials=trials, trial_minutes=trial_minutes, reports=reports,
            address=address, resume=resume, seed=seed,
            update=lambda s: live.update(_view(s, trials)),
        )  # fmt: skip
        live.update(_view(state, trials))
    unfinished = [t for t in state.trials.values() if t["status"] == "running"]
    if unfinished or len(state.trials) < trials:
        console.print(f"sweep interrupted: resume it with --resume --out {escape(str(out))}")
    best = state.best()
    if best is not None:
        console.print(f"best trial {best['id']}: objective {best['objective']:.4f}; "
                      f"config in {escape(str(out / 'best.toml'))}", highlight=False)  # fmt: skip
    console.print(f"results: {escape(str(out / 'results.csv'))}", highlight=False)
