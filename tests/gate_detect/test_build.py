"""`build-detector`: a whole detector from a build file (tiny datasets and networks), resumed
after an interruption without redoing finished steps; bad build files are one-line errors."""

from __future__ import annotations

import json
import time
from pathlib import Path

import pytest
from typer.testing import CliRunner

from icarus_vision.cli import app
from icarus_vision.gate_detect.registry import make_detector
from tests.gate_detect.conftest import gate_image, write_recipe

runner = CliRunner()

BUILD = """
name = "tiny"
[[datasets]]
name = "a"
recipe = "{recipe}"
images = 16
seed = 1
[[datasets]]
name = "b"
recipe = "{recipe}"
images = 16
seed = 2
[corner]
data = ["a:2", "b:1"]
epochs = 1
init = "shipped"
train = {{ batch_size = 8, bf16 = false, lr = 1e-5, tune_decode = false }}
model = {{ input_size = [256, 192] }}
[refiner]
data = ["b"]
val = ["a"]
epochs = 1
init = "shipped"
train = {{ batch_size = 16, lr = 1e-6, tune = false }}
[zoom]
data = ["a"]
val = ["b"]
epochs = 1
net = {{ patch = 16, widths = [4, 4, 8, 8], hidden = 8, min_side_px = 4.0 }}
[rescorer]
data = ["a"]
epochs = 2
[quantize]
data = ["b"]
images = 4
[evaluate]
data = ["b"]
"""


def test_a_detector_is_built_from_nothing_and_the_build_resumes(tmp_path, monkeypatch):
    recipe = write_recipe(tmp_path / "tiny.toml")  # 320x240 frames: the shipped networks' size
    recipe.write_text(
        recipe.read_text().replace("width = 160\nheight = 120", "width = 320\nheight = 240")
    )
    config = tmp_path / "build.toml"
    config.write_text(BUILD.format(recipe=recipe))
    out = tmp_path / "build"
    import icarus_vision.gate_detect.cnn.build as build

    real = build._zoom

    def interrupted(*args, **kwargs):
        time.sleep(0.5)  # a stage that ran a while before Ctrl-C
        raise KeyboardInterrupt

    monkeypatch.setattr(build, "_zoom", interrupted)
    r = runner.invoke(
        app, ["build-detector", "--config", str(config), "--out", str(out), "--workers", "1"]
    )
    assert r.exit_code != 0
    done = json.loads((out / "build.json").read_text())["steps"]
    assert set(done) == {"dataset a", "dataset b", "corner", "refiner"}
    assert json.loads((out / "build.json").read_text())["interrupted"]["zoom"] >= 0.5
    corner_weights = (out / "corner" / "best" / "model.safetensors").read_bytes()

    monkeypatch.setattr(build, "_zoom", real)
    r = runner.invoke(
        app, ["build-detector", "--config", str(config), "--out", str(out), "--workers", "1"]
    )
    assert r.exit_code == 0, r.output
    assert "corner: done before" in r.output and "refiner: done before" in r.output
    assert (out / "corner" / "best" / "model.safetensors").read_bytes() == corner_weights
    steps = json.loads((out / "build.json").read_text())["steps"]
    assert list(steps)[-5:] == ["zoom", "rescorer", "detector", "quantize", "evaluate"]
    assert "zoom: running (resumed after" in r.output
    assert steps["zoom"]["seconds"] >= 0.5  # the interrupted run's time counts
    assert json.loads((out / "build.json").read_text())["interrupted"] == {}
    meta = json.loads((out / "detector" / "detector.json").read_text())
    assert {"refine", "zoom", "rescore", "int8"} <= set(meta)
    config.write_text(config.read_text().replace("epochs = 2", "epochs = 3"))  # changed since
    r = runner.invoke(app, ["build-detector", "--config", str(config), "--out", str(out)])
    assert r.exit_code == 1 and "changed since" in r.output
    assert json.loads((out / "eval.json").read_text())["images"] == 4  # b's test split
    assert (out / "detector" / "error_model.json").is_file()
    det = make_detector(f"cnn:{out / 'detector'}")
    assert isinstance(det.detect(gate_image()), list)


@pytest.mark.parametrize(
    "text, needle",
    [
        ("[corner]\ndata = ['x']\n", "names no dataset"),
        (
            "[[datasets]]\nname = 'a'\nrecipe = 'gates-v1'\nimages = 4\n[refiner]\ndata = ['a']\n",
            "[corner]",
        ),
        (
            "[[datasets]]\nname = 'a'\nrecipe = 'gates-v1'\nimages = 4\n[corner]\ndata = ['a']\n[zoom]\ndata = ['a']\n",
            "needs a [refiner]",
        ),
        (
            "[[datasets]]\nname = 'a'\nrecipe = 'gates-v1'\nimages = 4\n[corner]\ndata = ['a']\nepoch = 3\n",
            "epoch",
        ),
        (
            "[[datasets]]\nname = 'a'\nimages = 4\n[corner]\ndata = ['a']\n",
            "needs name, recipe and images",
        ),
        ("[colour]\n", "unknown table"),
        (
            "[[datasets]]\nname = 'a'\nrecipe = 'gates-v1'\nimages = 4\n[corner]\ndata = ['a']\n"
            "[refiner]\ndata = ['a']\nval = ['a:2']\n",
            "are for the data of",
        ),
        (  # caught when the file is read, not after hours of rendering
            "[[datasets]]\nname = 'a'\nrecipe = 'gates-v1'\nimages = 4\n[corner]\ndata = ['a:0']\n",
            "a share must be > 0",
        ),
        (
            "[[datasets]]\nname = 'a'\nrecipe = 'gates-v1'\nimages = 4\n[corner]\ndata = ['a:x']\n",
            "names no dataset",
        ),
        (
            "[[datasets]]\nname = 'a'\nrecipe = 'gates-v1'\nimages = 4\n[corner]\ndata = ['a']\n"
            "[refiner]\ndata = ['a']\n[zoom]\nkeep = 'shipped'\n",
            "a kept zoom stage needs a kept refiner",
        ),
    ],
)
def test_bad_build_files_are_one_line_errors(tmp_path, text, needle):
    config = tmp_path / "b.toml"
    config.write_text(text)
    r = runner.invoke(
        app, ["build-detector", "--config", str(config), "--out", str(tmp_path / "o")]
    )
    lines = [s for s in r.output.strip().splitlines() if s.strip()]
    assert r.exit_code == 1 and len(lines) == 1 and needle in lines[0], r.output


def build_on_tiny_renders(tmp_path, stages: str) -> Path:
    """Run build-detector on 8 tiny 320x240 renders (dataset "a") with ``stages``; its detector."""
    recipe = write_recipe(tmp_path / "tiny.toml")
    recipe.write_text(
        recipe.read_text().replace("width = 160\nheight = 120", "width = 320\nheight = 240")
    )
    config = tmp_path / "build.toml"
    config.write_text(f'[[datasets]]\nname = "a"\nrecipe = "{recipe}"\nimages = 8\n{stages}')
    out = tmp_path / "build"
    r = runner.invoke(
        app, ["build-detector", "--config", str(config), "--out", str(out), "--workers", "1"]
    )
    assert r.exit_code == 0, r.output
    return out / "detector"


def test_a_build_fine_tunes_the_corner_network_and_keeps_the_shipped_later_stages(tmp_path):
    from icarus_vision.gate_detect.cnn.checkpoint import SHIPPED

    built = build_on_tiny_renders(
        tmp_path,
        """
[corner]
data = ["a"]
init = "shipped"
train = { batch_size = 8, bf16 = false, lr = 1e-5, tune_decode = false }
[refiner]
keep = "shipped"
[zoom]
keep = "shipped"
[rescorer]
keep = "shipped"
""",
    )
    meta = json.loads((built / "detector.json").read_text())
    shipped = json.loads((SHIPPED / "detector.json").read_text())
    for key in ("refine", "zoom", "rescore", "decode"):
        assert meta[key] == shipped[key]
    assert meta["model"]["input_size"] == shipped["model"]["input_size"]
    assert (built / "model.safetensors").read_bytes() != (
        SHIPPED / "model.safetensors"
    ).read_bytes()
    assert make_detector(f"cnn:{built}").detect(gate_image())


def test_a_build_keeps_the_shipped_corner_network_and_rescorer_around_trained_stages(tmp_path):
    """The later stages trained on the shipped corner network, the shipped rescorer put on them."""
    from icarus_vision.gate_detect.cnn.checkpoint import SHIPPED

    built = build_on_tiny_renders(
        tmp_path,
        """
[corner]
keep = "shipped"
[refiner]
data = ["a"]
init = "shipped"
train = { batch_size = 8, lr = 1e-5, tune = false }
[zoom]
data = ["a"]
train = { batch_size = 8 }
[rescorer]
keep = "shipped"
""",
    )
    shipped = SHIPPED
    for name in ("model.safetensors", "rescore.safetensors"):
        assert (built / name).read_bytes() == (shipped / name).read_bytes()
    for name in ("refiner.safetensors", "zoom.safetensors"):
        assert (built / name).read_bytes() != (shipped / name).read_bytes()
    meta = json.loads((built / "detector.json").read_text())
    assert meta["rescore"] == json.loads((shipped / "detector.json").read_text())["rescore"]
    assert meta["refine_training"]["init"] == str(shipped)
    assert make_detector(f"cnn:{built}").detect(gate_image())


def test_graft_takes_the_input_size_with_the_refiner_and_keeps_its_own_for_a_rescorer(tmp_path):
    """A refiner comes with the input size and decoding it was tuned with; a rescorer put on
    trained stages leaves theirs (the trained refiner's own tuning)."""
    import shutil

    from icarus_vision.gate_detect.cnn.build import graft
    from icarus_vision.gate_detect.cnn.checkpoint import SHIPPED

    tuned = tmp_path / "tuned"
    shutil.copytree(SHIPPED, tuned)
    meta = json.loads((tuned / "detector.json").read_text())
    shipped_size = list(meta["model"]["input_size"])
    meta["model"]["input_size"] = [320, 240]
    meta["decode"]["min_snapped"] = meta["decode"]["min_snapped"] + 1
    del meta["rescore"], meta["rescore_training"]
    (tuned / "detector.json").write_text(json.dumps(meta))
    (tuned / "rescore.safetensors").unlink()
    rescored = json.loads(
        (graft(tuned, SHIPPED, tmp_path / "r", ["rescorer"]) / "detector.json").read_text()
    )
    assert rescored["model"]["input_size"] == [320, 240]
    assert rescored["decode"] == meta["decode"] and rescored["refine"] == meta["refine"]
    assert (tmp_path / "r" / "rescore.safetensors").is_file()
    refined = json.loads(
        (graft(tuned, SHIPPED, tmp_path / "f", ["refiner"]) / "detector.json").read_text()
    )
    assert refined["model"]["input_size"] == shipped_size
    assert refined["decode"]["min_snapped"] == meta["decode"]["min_snapped"] - 1


def test_a_build_keeps_its_own_name_beside_its_datasets_names(tmp_path):
    from icarus_vision.gate_detect.cnn.build import load_build

    path = tmp_path / "b.toml"
    path.write_text(BUILD.format(recipe="gates-v1"))
    spec = load_build(path)
    assert spec.name == "tiny"
    assert [d.name for d in spec.datasets] == ["a", "b"]
