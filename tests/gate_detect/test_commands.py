"""`train-detector`, `train-refiner`, `train-zoom` and `eval-detector` on the command line: help, a run,
one-line errors."""

from __future__ import annotations

import json

import pytest
import typer
from typer.testing import CliRunner

from icarus_vision.cli import app

runner = CliRunner()


@pytest.mark.parametrize(
    "cmd", ["train-detector", "train-refiner", "train-zoom", "train-rescorer", "eval-detector"]
)
def test_help(cmd):
    r = runner.invoke(app, [cmd, "--help"])
    assert r.exit_code == 0 and "--data" in r.output


def test_eval_detector_writes_report_and_error_model(tiny_dataset, tmp_path):
    out = tmp_path / "r.json"
    em = tmp_path / "em.json"
    r = runner.invoke(app, ["eval-detector", "--data", str(tiny_dataset), "--detector", "opencv",
                            "--json", str(out), "--error-model", str(em),
                            "--examples", str(tmp_path / "ex.png"), "--resamples", "200",
                            "--seed", "3"])  # fmt: skip
    assert r.exit_code == 0, r.output
    report = json.loads(out.read_text())
    assert report["detector"] == "opencv" and report["confidence"]["resamples"] == 200
    assert report["backend"] is None  # a CNN's: what ran its networks
    assert "95 % intervals" in r.output
    assert "distance_m" in json.loads(em.read_text())
    import cv2

    sheet = cv2.imread(str(tmp_path / "ex.png"))  # 4 test images of 160x120, drawn at 2x
    assert sheet is not None and sheet.shape == (240, 4 * 320, 3)


def test_eval_detector_reads_the_split_asked_for(tiny_dataset, tmp_path):
    out = tmp_path / "r.json"
    r = runner.invoke(app, ["eval-detector", "--data", str(tiny_dataset), "--detector", "opencv",
                            "--split", "val", "--json", str(out), "--resamples", "0"])  # fmt: skip
    assert r.exit_code == 0, r.output
    report = json.loads(out.read_text())
    assert report["split"] == "val" and report["images"] == 4  # the tiny dataset's val split
    assert "4 val images" in r.output and "by apparent size" in r.output
    r = runner.invoke(app, ["eval-detector", "--data", str(tiny_dataset), "--split", "tset"])
    assert r.exit_code == 2 and "expected one of train, val, test" in r.output


def test_eval_detector_min_score_counts_only_the_surer_gates(tiny_dataset, tmp_path):
    reports = {}
    for score in (None, "1.0"):
        out = tmp_path / f"r{score}.json"
        extra = [] if score is None else ["--min-score", score]
        r = runner.invoke(app, ["eval-detector", "--data", str(tiny_dataset), "--json", str(out),
                                "--resamples", "0", *extra])  # fmt: skip
        assert r.exit_code == 0, r.output
        reports[score] = json.loads(out.read_text())
    assert reports[None]["min_score"] is None and reports["1.0"]["min_score"] == 1.0
    assert reports["1.0"]["false_positives"] <= reports[None]["false_positives"]
    if reports[None]["gates"]:
        assert reports["1.0"]["recall"] <= reports[None]["recall"]
    assert "gates scored >= 1" in r.output
    r = runner.invoke(app, ["eval-detector", "--data", str(tiny_dataset), "--min-score", "2"])
    assert r.exit_code == 2 and "--min-score" in r.output
    r = runner.invoke(app, ["eval-detector", "--data", str(tiny_dataset), "--detector", "opencv",
                            "--min-score", "0.5"])  # fmt: skip
    assert r.exit_code != 0 and "min_score" in r.output


@pytest.mark.parametrize(
    "args, needle",
    [
        (["eval-detector", "--data", "{tmp}/missing", "--detector", "opencv"], "missing"),
        (["eval-detector", "--data", "{data}", "--detector", "nosuch"], "nosuch"),
        (  # refused before any evaluation (the data folder is not even looked at)
            ["eval-detector", "--data", "{tmp}/missing", "--examples", "{tmp}/ex.xyz"],
            "cannot write an image of this type",
        ),
        (["eval-detector", "--data", "{data}", "--detector", "cnn:{tmp}/none.safetensors"], "none"),
        (["train-detector", "--data", "{tmp}/missing", "--out", "{tmp}/o"], "missing"),
        (
            ["train-detector", "--data", "{data}", "--out", "{tmp}/o", "--resume"],
            "nothing to resume",
        ),
        (
            ["train-detector", "--data", "{data}", "--out", "{tmp}/o", "--widths", "16,32"],
            "--widths",
        ),
        (["train-detector", "--data", "{data}", "--out", "{tmp}/o", "--widths", "a,b,c,d"], "a,b"),
        (["train-refiner", "--data", "{tmp}/missing", "--out", "{tmp}/o"], "missing"),
        (
            ["train-refiner", "--data", "{data}", "--out", "{tmp}/o", "--resume"],
            "nothing to resume",
        ),
        (
            ["train-refiner", "--data", "{data}", "--out", "{tmp}/o", "--patch", "20"],
            "multiple of 8",
        ),
        (
            ["train-refiner", "--data", "{data}", "--out", "{tmp}/o", "--detector", "{tmp}/none"],
            "none",
        ),
        (
            ["train-refiner", "--data", "{data}", "--out", "{tmp}/o", "--widths", "8,16"],
            "expected 3 positive integers",
        ),
        (["train-zoom", "--data", "{data}", "--out", "{tmp}/o", "--resume"], "nothing to resume"),
        (["train-zoom", "--data", "{data}", "--out", "{tmp}/o", "--patch", "20"], "multiple of 8"),
        (
            ["train-zoom", "--data", "{data}", "--out", "{tmp}/o", "--widths", "8,16"],
            "expected 4 positive integers",
        ),
        (
            ["train-zoom", "--data", "{data}", "--out", "{tmp}/o", "--detector", "{tmp}/none"],
            "none",
        ),
    ],
)
def test_errors_are_one_line(tiny_dataset, tmp_path, args, needle):
    args = [a.format(tmp=tmp_path, data=tiny_dataset) for a in args]
    r = runner.invoke(app, args)
    assert r.exit_code == 1
    lines = [s for s in r.output.strip().splitlines() if s.strip()]
    assert len(lines) == 1 and lines[0].startswith("error:") and needle in lines[0], r.output


def test_train_detector_builds_the_network_asked_for(tiny_dataset, tmp_path):
    out = tmp_path / "run"
    r = runner.invoke(app, ["train-detector", "--data", str(tiny_dataset), "--out", str(out),
                            "--epochs", "1", "--widths", "4,8,8,16", "--head-width", "8"])  # fmt: skip
    assert r.exit_code == 0, r.output
    model = json.loads((out / "best" / "detector.json").read_text())["model"]
    assert model["widths"] == [4, 8, 8, 16] and model["head_width"] == 8


def test_train_detector_help_states_the_model_defaults():
    """--widths and --head-width print their defaults as literals (to keep torch out of CLI start);
    they must follow ModelConfig."""
    from icarus_vision.gate_detect.cnn.model import ModelConfig

    params = {p.name: p for p in typer.main.get_command(app).commands["train-detector"].params}
    default = ModelConfig()
    assert f"(default: {','.join(map(str, default.widths))})" in params["widths"].help
    assert f"(default: {default.head_width})" in params["head_width"].help


def test_train_refiner_builds_the_refiner_asked_for_and_tunes_it(tiny_dataset, tmp_path):
    from icarus_vision.gate_detect.cnn.refine import RefineConfig

    out = tmp_path / "run"
    r = runner.invoke(app, ["train-refiner", "--data", str(tiny_dataset), "--out", str(out),
                            "--epochs", "1", "--patch", "24", "--widths", "4,8,8",
                            "--hidden", "8"])  # fmt: skip
    assert r.exit_code == 0, r.output
    refine = json.loads((out / "best" / "detector.json").read_text())["refine"]
    assert refine["widths"] == [4, 8, 8] and refine["hidden"] == 8 and refine["patch"] == 24
    # tuned on val: a threshold and a mirror setting from the grids
    assert isinstance(refine["mirror"], bool) and 0.1 <= refine["threshold"] <= 0.4
    params = {p.name: p for p in typer.main.get_command(app).commands["train-refiner"].params}
    default = RefineConfig()
    assert params["widths"].default == ",".join(map(str, default.widths))
    assert params["hidden"].default == default.hidden
    assert params["square_hfov"].default == default.square_hfov_deg


def test_corrupt_training_state_is_a_one_line_error(tmp_path):
    import torch

    from icarus_vision.gate_detect.cnn.train import load_state

    bad = tmp_path / "train_state.pt"
    bad.write_bytes(b"not a torch file")
    opt = torch.optim.SGD([torch.nn.Parameter(torch.zeros(1))], lr=0.1)
    sched = torch.optim.lr_scheduler.StepLR(opt, 1)
    with pytest.raises(ValueError, match="train_state.pt: corrupt training state"):
        load_state(bad, opt, sched)
