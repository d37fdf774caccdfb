"""`icarus-vision eval-policy`: success rate, crashes and lap times over many episodes."""

from __future__ import annotations

from pathlib import Path

import typer
from rich.markup import escape
from rich.table import Table

from icarus_vision.cli import app, console, user_errors


@app.command("eval-policy")
@user_errors
def eval_policy_cmd(
    policy: str = typer.Option(
        "default", help="Exported policy path, 'default' (shipped) or 'scripted'."
    ),
    track: str = typer.Option(
        None, help="Built-in track name or TOML path (default: random tracks)."
    ),
    gates: int = typer.Option(10, min=1, help="Gates per random track."),
    episodes: int = typer.Option(100, min=1, help="Episodes."),
    backend: str = typer.Option("batched", help="batched or pybullet."),
    randomize: bool = typer.Option(
        False, "--randomize/--no-randomize", help="Domain randomisation."
    ),
    seed: int = typer.Option(0, help="Random seed."),
    json_path: Path = typer.Option(None, "--json", help="Write the results to this JSON file."),
) -> None:
    """Fly a policy for N episodes and report success, crashes, gates, lap times and speed."""
    from icarus_vision.fileio import atomic_write_json
    from icarus_vision.policy.evaluate import evaluate_policy
    from icarus_vision.policy.pilots import resolve_policy

    pilot = resolve_policy(policy)
    r = evaluate_policy(pilot, track, episodes=episodes, num_gates=gates, backend=backend,
                        randomize=randomize, seed=seed)  # fmt: skip
    table = Table(title=f"eval-policy: {r['policy']} on {r['track']} ({r['backend']})")
    table.add_column("metric")
    table.add_column("value")
    lt = r["lap_time_s"]
    rows = [
        ("episodes", str(r["episodes"])),
        ("success rate", f"{r['success_rate']:.1%}"),
        ("crash rate", f"{r['crash_rate']:.1%} {r['crash_reasons'] or ''}"),
        ("mean gates passed", f"{r['mean_gates_passed']:.2f}"),
        (
            "lap time [s] median (p10-p90)",
            "-"
            if lt["median"] is None
            else f"{lt['median']:.2f} ({lt['p10']:.2f}-{lt['p90']:.2f})",
        ),
        ("max / mean speed [m/s]", f"{r['max_speed_mps']:.1f} / {r['mean_speed_mps']:.1f}"),
    ]
    for k, v in rows:
        table.add_row(escape(k), escape(v))
    console.print(table)
    if json_path is not None:
        atomic_write_json(json_path, r)
