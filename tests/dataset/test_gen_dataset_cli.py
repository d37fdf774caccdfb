"""`icarus-vision gen-dataset` through Typer's CliRunner: help, a tiny run, one-line errors."""

from __future__ import annotations

import json

import pytest
from typer.testing import CliRunner

from icarus_vision.cli import app

from .conftest import write_recipe

runner = CliRunner()


def test_help_lists_the_options():
    res = runner.invoke(app, ["gen-dataset", "--help"])
    assert res.exit_code == 0
    for opt in (
        "--recipe",
        "--out",
        "--num-images",
        "--workers",
        "--seed",
        "--force",
        "--renderer",
    ):
        assert opt in res.output


def test_tiny_run_then_resume(tiny_recipe, tmp_path):
    out = tmp_path / "ds"
    args = ["gen-dataset", "--recipe", str(tiny_recipe), "--out", str(out), "--num-images", "5"]
    res = runner.invoke(app, [*args, "--workers", "1", "--seed", "2"])
    assert res.exit_code == 0, res.output
    assert "5 images" in res.output and "img/s" in res.output
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["seed"] == 2 and manifest["num_images"] == 5
    res = runner.invoke(app, [*args, "--workers", "1", "--seed", "2"])
    assert res.exit_code == 0 and "kept 3" in res.output
    res = runner.invoke(app, [*args, "--seed", "7"])
    assert res.exit_code == 1
    assert "holds a different dataset" in res.output and "--force" in res.output


def _one_line_error(res) -> str:
    lines = [ln for ln in res.output.splitlines() if ln.strip()]
    assert res.exit_code == 1 and len(lines) == 1 and "Traceback" not in res.output, res.output
    return lines[0]


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--num-images", "0"], "num_images must be an integer >= 1"),
        (["--workers", "0"], "workers must be an integer >= 1"),
        (["--seed", "-3"], "seed must be an integer >= 0"),
    ],
)
def test_bad_numbers_give_one_line_errors(tiny_recipe, tmp_path, extra, message):
    res = runner.invoke(
        app, ["gen-dataset", "--recipe", str(tiny_recipe), "--out", str(tmp_path / "o"), *extra]
    )
    assert message in _one_line_error(res)


def test_unknown_renderer_gives_a_one_line_error(tiny_recipe, tmp_path):
    args = ["--recipe", str(tiny_recipe), "--out", str(tmp_path / "o"), "--renderer", "opengl"]
    res = runner.invoke(app, ["gen-dataset", *args])
    assert "renderer must be one of tiny, egl, got 'opengl'" in _one_line_error(res)
    assert not (tmp_path / "o").exists()


def test_missing_and_malformed_recipes_give_one_line_errors(tmp_path):
    res = runner.invoke(
        app, ["gen-dataset", "--recipe", str(tmp_path / "nope.toml"), "--out", str(tmp_path / "o")]
    )
    assert "recipe file not found" in _one_line_error(res)
    bad = write_recipe(tmp_path / "bad.toml", frames_per_scene=0)
    res = runner.invoke(app, ["gen-dataset", "--recipe", str(bad), "--out", str(tmp_path / "o")])
    assert "dataset.frames_per_scene: must be >= 1" in _one_line_error(res)
    (tmp_path / "broken.toml").write_text("name = [unclosed")
    res = runner.invoke(
        app,
        ["gen-dataset", "--recipe", str(tmp_path / "broken.toml"), "--out", str(tmp_path / "o")],
    )
    assert "not a valid TOML file" in _one_line_error(res)
    assert not (tmp_path / "o").exists()


def test_recipe_and_out_are_required():
    res = runner.invoke(app, ["gen-dataset"])
    assert res.exit_code != 0 and "--recipe" in res.output
