from __future__ import annotations

import json

import pytest
from typer.testing import CliRunner

from icarus_vision.cli import app

runner = CliRunner()


def test_help_on_every_command():
    res = runner.invoke(app, ["--help"])
    assert res.exit_code == 0
    for cmd in ("tracks", "race"):
        res = runner.invoke(app, [cmd, "--help"])
        assert res.exit_code == 0 and "Usage" in res.output


@pytest.mark.parametrize(
    "cmd, text",
    [("train-detector", "default: 32"), ("train-zoom", "default: the shipped one"),
     ("train-refiner", "default: the first --data")],
)  # fmt: skip
def test_help_shows_defaults_written_in_the_text(cmd, text):
    # rich help drops a "[default: ...]" written into a help text; "(default: ...)" stays
    res = runner.invoke(app, [cmd, "--help"])
    assert res.exit_code == 0 and text in " ".join(res.output.replace("│", " ").split())


def test_tracks_lists_builtin_tracks():
    res = runner.invoke(app, ["tracks"])
    assert res.exit_code == 0
    for name in ("single-gate", "ten-gates", "grand-prix"):
        assert name in res.output


def test_race_writes_report_and_plot(tmp_path):
    out = tmp_path / "run"
    res = runner.invoke(
        app,
        [
            "race",
            "--track",
            "single-gate",
            "--backend",
            "batched",
            "--detector",
            "oracle",
            "--policy",
            "scripted",
            "--out",
            str(out),
            "--json",
            str(tmp_path / "r.json"),
        ],
    )
    assert res.exit_code == 0, res.output
    report = json.loads((tmp_path / "r.json").read_text())
    assert report["finished"] and report["track"] == "single-gate"
    assert (out / "trajectory.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert (out / "race.mp4").stat().st_size > 1000


def test_train_detector_bad_input_size_is_one_line_error(tmp_path):
    res = runner.invoke(app, ["train-detector", "--data", str(tmp_path), "--out",
                              str(tmp_path / "o"), "--input-size", "256"])  # fmt: skip
    assert res.exit_code == 1 and "--input-size: expected WxH" in res.output
    assert "Traceback" not in res.output
    res = runner.invoke(app, ["train-detector", "--data", str(tmp_path), "--out",
                              str(tmp_path / "o"), "--init", str(tmp_path), "--widths", "8,8,8,8"])  # fmt: skip
    assert res.exit_code == 1 and "--init takes the checkpoint's network" in res.output


@pytest.mark.parametrize(
    "args, msg",
    [
        (["race", "--track", "nowhere"], "built-in tracks: single-gate"),
        (["race", "--detector", "sonar"], "sonar"),
        (["race", "--policy", "nope.safetensors"], "nope.safetensors: policy file not found"),
        (["race", "--track", "missing.toml"], "missing.toml: track file not found"),
        (["race", "--backend", "ode"], "unknown backend"),
        (["race", "--quad", "nope.toml"], "nope.toml: quadrotor file not found"),
    ],
)
def test_race_bad_input_is_one_line_error(args, msg, tmp_path):
    base = ["--detector", "oracle", "--policy", "scripted"]
    res = runner.invoke(app, [args[0], *base, *args[1:]])  # later options win
    assert res.exit_code == 1
    assert msg in res.output
    assert "Traceback" not in res.output


def test_bad_track_file_names_file_and_gate(tmp_path):
    p = tmp_path / "bad.toml"
    p.write_text('name="x"\n[start]\npos=[0,0,0.2]\n[[gates]]\npos=[5,0,2]\nsize=0.0\n')
    res = runner.invoke(
        app, ["race", "--track", str(p), "--detector", "oracle", "--policy", "scripted"]
    )
    assert res.exit_code == 1 and "bad.toml gate 0: size must be > 0" in res.output


def test_error_text_with_brackets_is_printed_verbatim(tmp_path):
    p = tmp_path / "b.toml"
    p.write_text('name="x"\n[start]\npos=[0,0]\n[[gates]]\npos=[5,0,2]\n')
    res = runner.invoke(
        app, ["race", "--track", str(p), "--detector", "oracle", "--policy", "scripted"]
    )
    assert res.exit_code == 1 and "b.toml [start]: start.pos must be a list of 3" in res.output


def test_plan_command_and_race_reports_time_optimal(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    res = runner.invoke(app, ["plan", "--track", "single-gate", "--json", "plan.json"])
    assert res.exit_code == 0, res.output
    summary = json.loads((tmp_path / "plan.json").read_text())
    assert summary["time_optimal_s"] >= summary["point_mass_s"] > 0
    res = runner.invoke(app, ["race", "--track", "single-gate", "--detector", "oracle", "--policy", "scripted",
                              "--no-video", "--json", "r.json", "--out", "r"])  # fmt: skip
    assert res.exit_code == 0, res.output
    report = json.loads((tmp_path / "r.json").read_text())
    assert report["time_optimal_s"] == pytest.approx(summary["time_optimal_s"], abs=1e-3)
    assert report["time_optimal_ratio"] > 1.0
    assert (tmp_path / "r" / "trajectory.png").is_file()  # drawn with the plan as a ghost
    res = runner.invoke(
        app, ["eval-policy", "--track", "single-gate", "--episodes", "4", "--json", "e.json"]
    )
    assert res.exit_code == 0, res.output
    ev = json.loads((tmp_path / "e.json").read_text())
    assert ev["time_optimal_s"] == pytest.approx(summary["time_optimal_s"], abs=1e-3)
    assert ev["time_optimal_ratio"] == pytest.approx(
        ev["lap_time_s"]["median"] / ev["time_optimal_s"], rel=1e-3
    )
    assert ev["time_optimal_ratio"] > 1.0
    res = runner.invoke(
        app, ["eval-policy", "--episodes", "2", "--gates", "2", "--json", "r2.json"]
    )
    random_tracks = json.loads((tmp_path / "r2.json").read_text())
    assert random_tracks["time_optimal_s"] is None and random_tracks["time_optimal_ratio"] is None


def test_race_refuses_a_policy_with_other_conventions(tmp_path):
    import shutil

    from icarus_vision.policy.pilots import default_policy_path

    src = default_policy_path()
    shutil.copy(src, tmp_path / "p.safetensors")
    desc = json.loads(src.with_suffix(".json").read_text())
    desc["action"] = "motor_speeds"
    (tmp_path / "p.json").write_text(json.dumps(desc))
    res = runner.invoke(
        app, ["race", "--detector", "oracle", "--policy", str(tmp_path / "p.safetensors")]
    )
    assert (
        res.exit_code == 1 and "action convention" in res.output and "Traceback" not in res.output
    )


def test_train_refiner_margin_must_leave_an_opening(tmp_path):
    res = runner.invoke(app, ["train-refiner", "--data", str(tmp_path), "--out",
                              str(tmp_path / "o"), "--patch", "32", "--margin", "16"])  # fmt: skip
    assert res.exit_code == 2 and "less than half the patch (32 px)" in res.output
    assert not (tmp_path / "o").exists()


RACE = ["race", "--track", "single-gate", "--detector", "oracle", "--policy", "scripted"]


@pytest.mark.parametrize(
    "args",
    [
        [*RACE, "--out", "{f}/sub"],
        [*RACE, "--json", "{f}/x.json"],
        ["eval-policy", "--episodes", "1", "--json", "{f}/x.json"],
        ["plan", "--track", "single-gate", "--json", "{f}/x.json"],
        ["eval-estimator", "--track", "single-gate", "--detector", "oracle", "--out", "{f}/sub"],
        ["eval-detector", "--data", "{f}", "--detector", "opencv", "--json", "{f}/x.json"],
    ],
)
def test_outputs_under_a_file_are_refused_before_any_work(tmp_path, args):
    f = tmp_path / "a-file"
    f.write_text("keep me")
    res = runner.invoke(app, [a.format(f=f) for a in args])
    assert res.exit_code != 0
    assert "Traceback" not in res.output and "is a file" in res.output
    assert f.read_text() == "keep me"


def test_race_summary_of_a_crash_with_a_cached_plan(tmp_path, monkeypatch):
    """A race that does not finish on a planned track has no ratio: the summary prints '-'."""
    import icarus_vision.racing.runner as runner_mod

    real = runner_mod.run_race

    def crashed(*args, **kwargs):
        result = real(*args, **kwargs)
        result.report.update(finished=False, crashed=True, crash_reason="ground",
                             time_optimal_s=3.0, time_optimal_ratio=None, total_time_s=None)  # fmt: skip
        return result

    monkeypatch.setattr(runner_mod, "run_race", crashed)
    res = runner.invoke(app, [*RACE, "--no-video", "--out", str(tmp_path / "o")])
    assert res.exit_code == 0, res.output
    assert "3.00 / -" in res.output
    assert json.loads((tmp_path / "o" / "report.json").read_text())["time_optimal_ratio"] is None


def test_sigterm_stops_a_long_command_as_ctrl_c_does():
    """train-policy and build-detector turn SIGTERM into KeyboardInterrupt, so a scheduler's stop
    saves their state the way Ctrl-C does."""
    import os
    import signal
    import time

    from icarus_vision.cli import stop_on_sigterm

    old = signal.getsignal(signal.SIGTERM)
    try:
        stop_on_sigterm()
        with pytest.raises(KeyboardInterrupt):
            os.kill(os.getpid(), signal.SIGTERM)
            time.sleep(5)  # the handler runs at once: never reached
    finally:
        signal.signal(signal.SIGTERM, old)


def test_eval_policy_and_race_take_the_lookahead_filter(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    res = runner.invoke(app, ["eval-policy", "--episodes", "2", "--gates", "2", "--lookahead",
                              "--json", "e.json"])  # fmt: skip
    assert res.exit_code == 0, res.output
    assert "look-ahead" in res.output
    assert json.loads((tmp_path / "e.json").read_text())["lookahead"] is True
    res = runner.invoke(app, ["race", "--track", "single-gate", "--detector", "oracle", "--lookahead",
                              "--no-video", "--json", "r.json", "--out", "r"])  # fmt: skip
    assert res.exit_code == 0, res.output
    assert json.loads((tmp_path / "r.json").read_text())["policy"] == "default+lookahead"
    res = runner.invoke(app, ["eval-policy", "--episodes", "2", "--gates", "2", "--lookahead-race",
                              "--json", "e.json"])  # fmt: skip
    assert res.exit_code == 0, res.output
    assert json.loads((tmp_path / "e.json").read_text())["lookahead_race"] is True
