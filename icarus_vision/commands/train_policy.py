"""`icarus-vision train-policy`: PPO on the batched backend with curriculum and randomisation."""

from __future__ import annotations

import time
from dataclasses import replace
from datetime import datetime
from pathlib import Path

import typer
from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

from icarus_vision.cli import app, console, stop_on_sigterm, user_errors


@app.command("train-policy")
@user_errors
def train_policy_cmd(
    config: Path = typer.Option(
        None, help="Training config TOML (keys of TrainConfig; `preset` picks the base)."
    ),
    preset: str = typer.Option(
        None,
        help="Start from a preset: fast (default), classic, racing (the racing generalist) or "
        "specialist (the default with --track).",
    ),
    track: str = typer.Option(
        None,
        help="Train a specialist on this track (built-in name or TOML path) instead of random "
        "tracks; without --config or --preset the specialist preset is used.",
    ),
    quad: Path = typer.Option(
        None,
        help="Quadrotor TOML file to train for: its dynamics and its camera (the camera-angle cost "
        "and the out-of-view rule); default: the config's, else the built-in racer-500g.",
    ),
    init: str = typer.Option(
        None,
        help="Start the actor from an exported policy: default (the shipped generalist), a shipped "
        "name or a path. Its observation and layers must match the config's.",
    ),
    timesteps: int = typer.Option(
        None, min=1, help="Environment steps (default: the config's total_timesteps)."
    ),
    out: Path = typer.Option(None, help="Run folder (default: runs/policy-<timestamp>/)."),
    seed: int = typer.Option(0, help="Random seed."),
    resume: bool = typer.Option(
        False,
        "--resume",
        help="Continue the run in --out from its last checkpoint, with the run's own config "
        "(a different --config is refused).",
    ),
    error_model: Path = typer.Option(None, help="Detector error model JSON for perception noise."),
    max_minutes: float = typer.Option(
        None, min=0.0, help="Stop (and save) after this much wall-clock training."
    ),
) -> None:
    """Train a racing policy with PPO (progress bar, TensorBoard logs under OUT/tb, Ctrl-C saves)."""
    from icarus_vision.policy.config import PRESETS, load_run_config, load_train_config
    from icarus_vision.policy.train import train_policy

    explicit = any(v is not None for v in (config, preset, track, quad, init, error_model))
    if resume and out is not None and not explicit:
        cfg = load_run_config(out)  # the run's own settings
    elif config is not None:
        cfg = load_train_config(config)
    else:
        if preset is not None and preset not in PRESETS:
            raise ValueError(f"unknown preset {preset!r}; choose one of {', '.join(PRESETS)}")
        cfg = PRESETS[preset or ("specialist" if track is not None else "fast")]
    if track is not None:
        from icarus_vision.sim.builtin import resolve_track

        resolve_track(track)  # a bad name or file fails before anything is written
        cfg = replace(cfg, track=track)
    if quad is not None:
        cfg = replace(cfg, quad=str(quad))
    if init is not None:
        cfg = replace(cfg, init=init)
    if error_model is not None:
        if not error_model.is_file():
            raise FileNotFoundError(f"{error_model}: error model file not found")
        cfg = replace(cfg, perception=replace(cfg.perception, error_model=str(error_model)))
    if resume and out is None:
        raise ValueError("--resume needs --out: the run folder to continue")
    out = out or Path("runs") / f"policy-{datetime.now():%Y%m%d-%H%M%S}"
    total = timesteps or cfg.total_timesteps
    console.print(
        f"training [bold]{cfg.preset}[/] preset for {total:,} steps -> {out}/ (TensorBoard: {out}/tb)"
    )
    columns = [TextColumn("{task.description}"), BarColumn(), TextColumn("{task.completed:,.0f}/{task.total:,.0f}"),
               TextColumn("{task.fields[rate]} steps/s"), TextColumn("stage {task.fields[stage]} · {task.fields[gates]} gates · success {task.fields[success]}"),
               TimeElapsedColumn(), TimeRemainingColumn()]  # fmt: skip
    # SIGTERM (a scheduler stopping the job) saves a checkpoint exactly like Ctrl-C.
    stop_on_sigterm()
    t0 = time.perf_counter()
    with Progress(*columns, console=console, transient=False) as bar:
        task = bar.add_task("PPO", total=total, rate="-", stage=0, gates="-", success="-")
        last = [0.0]

        def progress(ts: int, curriculum) -> None:
            now = time.perf_counter()
            if now - last[0] > 0.5:
                last[0] = now
                bar.update(task, completed=ts, rate=f"{ts / max(now - t0, 1e-9):,.0f}", stage=curriculum.stage,
                           gates=curriculum.num_gates, success=f"{curriculum.success_rate():.0%}")  # fmt: skip

        try:
            result = train_policy(
                cfg, out, seed=seed, resume=resume, timesteps=total, progress=progress,
                max_wall_s=None if max_minutes is None else 60.0 * max_minutes,
            )  # fmt: skip
        except KeyboardInterrupt:
            console.print(f"interrupted: checkpoint saved; continue with --resume --out {out}")
            raise
    console.print(
        f"done: {result.timesteps:,} steps, curriculum stage {result.stage} ({result.num_gates} gates); "
        f"policy {result.policy_path}"
    )
