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
        "auto",
        help="auto (the track's shipped specialist if there is one, else the generalist), default "
        "(the generalist), a shipped name such as grand-prix-specialist, an exported policy path, "
        "or scripted.",
    ),
    track: str = typer.Option(
        None, help="Built-in track name or TOML path (default: random tracks)."
    ),
    gates: int = typer.Option(10, min=1, help="Gates per random track."),
    quad: Path = typer.Option(None, help="Quadrotor TOML file (default: the built-in racer-500g)."),
    difficulty: float = typer.Option(
        None,
        min=0.0,
        max=1.0,
        help="Random tracks: race layouts of this difficulty (0 classic ranges to 1 the full "
        "ranges and motifs; see race_track). Default: the classic random_track layouts.",
    ),
    plan: bool = typer.Option(
        False,
        "--plan",
        help="Solve the track's time-optimal plan when none is cached, for time_optimal_s and "
        "time_optimal_ratio (a cached plan is always used).",
    ),
    episodes: int = typer.Option(100, min=1, help="Episodes."),
    backend: str = typer.Option(
        "batched",
        help="batched (all episodes at once), pybullet, mujoco, or an installed plug-in's name "
        "(one episode after another).",
    ),
    randomize: bool = typer.Option(
        False, "--randomize/--no-randomize", help="Domain randomisation."
    ),
    lookahead: bool = typer.Option(
        False,
        "--lookahead/--no-lookahead",
        help="Fly the policy through the look-ahead safety filter: each step the next 0.6 s are "
        "predicted in the nominal quadrotor model, and where the policy's own flight would crash "
        "the clearest of 40 corrected actions is flown instead.",
    ),
    lookahead_race: bool = typer.Option(
        False,
        "--lookahead-race",
        help="The look-ahead filter in its racing mode (implies --lookahead): also where the "
        "policy's flight is clear, pitch offsets of ±0.25 and ±0.5 held 0.2 s are predicted and "
        "the one that gets furthest is flown when it keeps 0.3 m more from the frames; faster "
        "laps, a few times slower to compute.",
    ),
    seed: int = typer.Option(0, help="Random seed."),
    json_path: Path = typer.Option(None, "--json", help="Write the results to this JSON file."),
) -> None:
    """Fly a policy for N episodes and report success, crashes, gates, lap times and speed.

    On a fixed track with a time-optimal plan (cached by `plan`, or solved with --plan) it also
    reports time_optimal_s and time_optimal_ratio: the median lap over the plan's minimum time.
    """
    from icarus_vision.fileio import atomic_write_json, check_output
    from icarus_vision.policy.evaluate import evaluate_policy, time_optimal_fields
    from icarus_vision.policy.lookahead import racing
    from icarus_vision.policy.pilots import resolve_policy
    from icarus_vision.sim.builtin import resolve_track
    from icarus_vision.sim.quad import load_quad

    check_output(json_path)
    base = None if track is None else resolve_track(track)
    quad_params = None if quad is None else load_quad(quad)
    pilot = resolve_policy(policy, track=base)
    r = evaluate_policy(pilot, track, episodes=episodes, num_gates=gates, backend=backend,
                        randomize=randomize, seed=seed, difficulty=difficulty, quad=quad_params,
                        lookahead=racing() if lookahead_race else lookahead)  # fmt: skip
    r.update(time_optimal_fields(base, r["lap_time_s"]["median"], solve=plan, quad=quad_params))
    if json_path is not None:  # results first: nothing printed below can lose them
        atomic_write_json(json_path, r)
    filtered = ", look-ahead" if r["lookahead"] else ""
    filtered += " (racing)" if r["lookahead_race"] else ""
    table = Table(title=f"eval-policy: {r['policy']} on {r['track']} ({r['backend']}{filtered})")
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
    if r["time_optimal_s"] is not None:
        ratio = r["time_optimal_ratio"]
        rows.append(("time-optimal [s] / median lap ratio",
                     f"{r['time_optimal_s']:.2f} / {'-' if ratio is None else f'{ratio:.3f}'}"))  # fmt: skip
    for k, v in rows:
        table.add_row(escape(k), escape(v))
    console.print(table)
