"""`icarus-vision race`: fly a course headless with the whole pipeline; report, plot and video."""

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
    detector: str = typer.Option(
        "cnn", help="cnn[:PATH], opencv, or oracle (true gate position, no camera)."
    ),
    policy: str = typer.Option(
        "auto",
        help="auto (the track's shipped specialist if there is one, else the generalist), default "
        "(the generalist), a shipped name such as grand-prix-specialist, an exported policy path, "
        "or scripted.",
    ),
    backend: str = typer.Option(
        "pybullet",
        help="Physics backend: pybullet, mujoco, batched, or an installed plug-in's name (the "
        "camera renders through PyBullet whichever flies).",
    ),
    randomize: bool = typer.Option(
        False,
        "--randomize/--no-randomize",
        help="Randomise mass, wind and gates, and how the world looks (from --recipe).",
    ),
    recipe: str = typer.Option(
        "gates-v1",
        help="With --randomize: the visual recipe the world's look is drawn from, once per race "
        "(gates-v1: the shipped detector's training data; gates-v3: real gates and places, halls, "
        "LEDs, sensor effects; gates-v4: gates-v3 with glossy hall floors; or a recipe TOML path). The camera stays the --quad file's.",
    ),
    latency: int = typer.Option(1, min=0, help="Perception latency in camera frames."),
    lookahead: bool = typer.Option(
        False,
        "--lookahead/--no-lookahead",
        help="Fly the policy through the look-ahead safety filter: each step the next 0.6 s are "
        "predicted in the nominal quadrotor model, on the gates as vision knows them, and where "
        "the policy's own flight would crash the clearest of 40 corrected actions is flown instead; "
        "a clear prediction is kept while the flight keeps to it. About halves the real-time factor "
        "(the report's policy reads NAME+lookahead).",
    ),
    lookahead_race: bool = typer.Option(
        False,
        "--lookahead-race",
        help="The look-ahead filter in its racing mode (implies --lookahead): also where the "
        "policy's flight is clear, pitch offsets of ±0.25 and ±0.5 held 0.2 s are predicted and "
        "the one that gets furthest is flown when it keeps 0.3 m more from the gates (the "
        "report's policy reads NAME+lookahead-race).",
    ),
    video: Path = typer.Option(None, help="Video path (default: OUT/race.mp4)."),
    no_video: bool = typer.Option(False, "--no-video", help="Skip the video (faster)."),
    json_path: Path = typer.Option(None, "--json", help="Also write the report to this JSON file."),
    out: Path = typer.Option(None, help="Output folder (default: runs/race-<timestamp>/)."),
) -> None:
    """Fly a race headless: camera -> detector -> estimator -> policy -> physics.

    Writes OUT/report.json, OUT/trajectory.png and OUT/race.mp4 (FPV with detections beside a top
    view, real time) and prints a summary.
    """
    from icarus_vision.fileio import atomic_write_json, check_output
    from icarus_vision.policy.lookahead import racing
    from icarus_vision.racing.plots import plot_trajectory
    from icarus_vision.racing.runner import run_race
    from icarus_vision.racing.video import write_video
    from icarus_vision.sim.quad import load_quad

    for path in (json_path, video):
        check_output(path)
    check_output(out, folder=True)
    quad_params = load_quad(quad) if quad is not None else None
    want_video = not no_video
    result = run_race(track, quad=quad_params, laps=laps, seed=seed, detector=detector, policy=policy,
                      backend=backend, randomize=randomize, latency_frames=latency, video=want_video,
                      recipe=recipe, lookahead=racing() if lookahead_race else lookahead)  # fmt: skip
    out = out or Path("runs") / f"race-{datetime.now():%Y%m%d-%H%M%S}"
    out.mkdir(parents=True, exist_ok=True)
    r = result.report
    atomic_write_json(out / "report.json", r)
    if json_path is not None:
        atomic_write_json(json_path, r)
    crash = result.pos[-1] if r["crashed"] else None
    title = f"{r['track']} · {r['policy']} · {r['detector']}"
    plot_trajectory(out / "trajectory.png", result.track, result.t, result.pos, result.speed,
                    crash, title=title, ghost=result.ghost)  # fmt: skip
    video_path = None
    if want_video:
        video_path = video or out / "race.mp4"
        fps = quad_params.camera.rate_hz if quad_params else 30.0
        write_video(video_path, result.video, fps)
    p = r["perception"]
    err = p["rel_gate_error_m"]
    rows = [
        ("gates", f"{r['gates_passed']}/{r['gates_total']}"),
        ("finished", str(r["finished"])),
        ("crash", r["crash_reason"] or "-"),
        ("lap times [s]", ", ".join(f"{x:.2f}" for x in r["lap_times_s"]) or "-"),
        ("max / mean speed [m/s]", f"{r['max_speed_mps']:.1f} / {r['mean_speed_mps']:.1f}"),
        ("real-time factor", f"{r['realtime_factor']:.2f}x"),
        (
            "frames / detection rate",
            f"{p['frames']} / {p['detection_rate']:.0%}"
            if p["detection_rate"] is not None
            else "-",
        ),
        (
            "gate error [m] median / p95",
            "-" if err["median"] is None else f"{err['median']:.3f} / {err['p95']:.3f}",
        ),
    ]
    if r["time_optimal_s"] is not None:
        ratio = r["time_optimal_ratio"]
        ratio_text = "-" if ratio is None else f"{ratio:.2f}"
        rows.append(("time-optimal [s] / ratio", f"{r['time_optimal_s']:.2f} / {ratio_text}"))
    table = Table(title=f"race: {escape(title)} · {r['backend']}")
    table.add_column("metric")
    table.add_column("value")
    for k, v in rows:
        table.add_row(escape(k), escape(v))
    console.print(table)
    console.print(f"report, plot{' and video' if video_path else ''} written to {out}/")
