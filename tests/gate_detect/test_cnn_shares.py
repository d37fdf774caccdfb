"""Shares of the training data (``--data DIR:SHARE``) in the detector's later stages: the refiner,
the zoom stage and the rescorer draw each dataset's share, a run without shares draws as before,
bad shares are one-line errors, and a build file gives those stages shares."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
from typer.testing import CliRunner

from icarus_vision.cli import app
from icarus_vision.gate_detect.cnn import CnnDetector, stage_train
from icarus_vision.gate_detect.cnn import refine_train as rt
from icarus_vision.gate_detect.cnn import rescore_train as st
from icarus_vision.gate_detect.cnn import zoom_train as zt
from icarus_vision.gate_detect.cnn.build import load_build
from icarus_vision.gate_detect.cnn.data import load_splits
from icarus_vision.gate_detect.cnn.refine import RefineConfig
from icarus_vision.gate_detect.cnn.rescore import RescoreConfig, features

from .conftest import facing_box
from .test_cnn_refine import _first_stage
from .test_cnn_rescore import _detector as _full_detector
from .test_cnn_zoom import CFG as ZOOM
from .test_cnn_zoom import _detector as _refined_detector
from .test_cnn_zoom import _labelled_detections

MIX = 1.0, 0.001
"""Two datasets (the tiny one twice: its first and second copies), the second nearly never drawn."""


def _recording(monkeypatch, module) -> list:
    """Every ``draw_order(rng, n, weights)`` of ``module``: (weights, drawn order)."""
    seen = []

    def draw_order(rng, n, weights=None):
        order = stage_train.draw_order(rng, n, weights)
        seen.append((weights, order))
        return order

    monkeypatch.setattr(module, "draw_order", draw_order)
    return seen


def _from_first(weights: np.ndarray, order: np.ndarray) -> float:
    """Fraction of the drawn examples that come from the first dataset (the heavier weight)."""
    return float(np.mean(weights[order] == weights.max()))


def test_draws_follow_the_weights_and_without_them_are_the_old_permutation():
    w = np.r_[np.full(100, 1.0 / 100), np.full(100, 0.001 / 100)]
    order = stage_train.draw_order(np.random.default_rng(0), 200, w)
    assert len(order) == 200 and np.mean(order < 100) > 0.99
    assert np.array_equal(stage_train.draw_order(np.random.default_rng(3), 50),
                          np.random.default_rng(3).permutation(50))  # fmt: skip


def test_refiner_draws_each_dataset_by_its_share(tiny_dataset, tmp_path, monkeypatch):
    seen = _recording(monkeypatch, rt)
    first = _first_stage(tmp_path)
    kw = {"epochs": 1, "config": rt.RefineTrainConfig(batch_size=64, tune=False),
          "refine_config": RefineConfig(patch=16, margin=4), "progress": False}  # fmt: skip
    rt.train_refiner(first, [(tiny_dataset, MIX[0]), (tiny_dataset, MIX[1])], tmp_path / "a", **kw)
    ((weights, order),) = seen
    assert set(np.round(weights * 8, 6)) == {1.0, 0.001}  # each image: share / 8 train images
    assert _from_first(weights, order) > 0.95
    meta = json.loads((tmp_path / "a" / "best" / "detector.json").read_text())
    assert meta["refine_training"]["shares"] == list(MIX)
    seen.clear()
    rt.train_refiner(first, [tiny_dataset, tiny_dataset], tmp_path / "b", **kw)
    ((weights, order),) = seen
    assert weights is None and sorted(order) == list(range(len(order)))  # every example once
    meta = json.loads((tmp_path / "b" / "best" / "detector.json").read_text())
    assert "shares" not in meta["refine_training"]


def test_zoom_stage_draws_each_dataset_by_its_share(tiny_dataset, tmp_path, monkeypatch):
    monkeypatch.setattr(zt, "detections", _labelled_detections)
    seen = _recording(monkeypatch, zt)
    det = _refined_detector(tmp_path)
    kw = {"epochs": 1, "zoom_config": ZOOM, "progress": False,
          "config": zt.ZoomTrainConfig(batch_size=64, min_gate_px=8.0)}  # fmt: skip
    zt.train_zoom(det, [(tiny_dataset, MIX[0]), (tiny_dataset, MIX[1])], tmp_path / "a", **kw)
    ((weights, order),) = seen
    assert set(np.round(weights * 8, 6)) == {1.0, 0.001}
    assert _from_first(weights, order) > 0.95
    with np.load(tmp_path / "a" / zt.EXAMPLES) as z:  # kept for a resumed run
        np.testing.assert_array_equal(z["weights"], weights)
    seen.clear()
    zt.train_zoom(det, [tiny_dataset, tiny_dataset], tmp_path / "b", **kw)
    ((weights, order),) = seen
    assert weights is None and sorted(order) == list(range(len(order)))
    with np.load(tmp_path / "b" / zt.EXAMPLES) as z:
        assert "weights" not in z.files


def test_rescorer_draws_its_rows_by_their_images_share(tiny_dataset, tmp_path, monkeypatch):
    def candidate_table(self, image):
        quads = np.stack([facing_box(20, 20, 40, 40), facing_box(30, 30, 100, 60)])
        return features(np.full(2, 0.5), np.full(2, 0.5), quads, quads, (160, 120)), quads

    monkeypatch.setattr(CnnDetector, "candidate_table", candidate_table)
    seen = _recording(monkeypatch, st)
    det = _full_detector(tmp_path / "ck")
    kw = {"net_cfg": RescoreConfig(hidden=(4,)), "cfg": st.RescoreTrainConfig(epochs=1),
          "progress": False, "log": lambda s: None, "backend": "torch"}  # fmt: skip
    out, _ = st.train_rescorer(det, [(tiny_dataset, MIX[0]), (tiny_dataset, MIX[1])],
                               tmp_path / "r", ["train"], **kw)  # fmt: skip
    ((weights, order),) = seen
    assert set(np.round(weights * 8, 6)) == {1.0, 0.001}  # a row: its image's share / 8 images
    assert _from_first(weights, order) > 0.9
    assert json.loads((out / "detector.json").read_text())["rescore_training"]["shares"] == [*MIX]
    seen.clear()
    st.train_rescorer(det, [tiny_dataset, tiny_dataset], tmp_path / "u", ["train"], **kw)
    ((weights, order),) = seen
    assert weights is None and sorted(order) == list(range(len(order)))


def test_a_coco_folder_at_the_camera_size_joins_the_refiners_training(tiny_dataset, tmp_path):
    coco = tmp_path / "coco"
    shutil.copytree(tiny_dataset / "images", coco / "images")
    shutil.copy(tiny_dataset / "annotations" / "train.json", coco / "labels.json")
    train = load_splits([tiny_dataset, coco], "train", None, shares=[3.0, 1.0])
    assert len(train.files) == 16
    np.testing.assert_allclose([train.weights[:8].sum(), train.weights[8:].sum()], [3.0, 1.0])
    with pytest.raises(FileNotFoundError, match="val.json"):
        load_splits([coco], "val")  # it has no val split to validate on


@pytest.mark.parametrize("cmd", ["train-detector", "train-refiner", "train-zoom",
                                 "train-rescorer"])  # fmt: skip
@pytest.mark.parametrize("share", ["x", "0", "-1", "inf"])
def test_a_bad_share_is_a_one_line_error_naming_the_argument(tiny_dataset, tmp_path, cmd, share):
    arg = f"{tiny_dataset}:{share}"
    r = CliRunner().invoke(app, [cmd, "--data", arg, "--out", str(tmp_path / "o")])
    lines = [s for s in r.output.strip().splitlines() if s.strip()]
    assert r.exit_code == 1 and len(lines) == 1, r.output
    assert f"--data {arg}" in lines[0] and "share" in lines[0]
    assert not (tmp_path / "o").exists()


def test_a_build_file_gives_the_later_stages_shares(tmp_path):
    config = tmp_path / "b.toml"
    sets = "".join(f"[[datasets]]\nname = '{n}'\nrecipe = 'gates-v1'\nimages = 4\n" for n in "ab")
    config.write_text(
        f"{sets}[corner]\ndata = ['a']\n[refiner]\ndata = ['a:2', 'b:1']\n"
        "[zoom]\ndata = ['a', 'b:0.5']\n[rescorer]\ndata = ['b:3']\n"
    )
    spec = load_build(config)
    assert spec.stages["refiner"].data == ("a:2", "b:1")
    assert spec.stages["rescorer"].data == ("b:3",)
    config.write_text(f"{sets}[corner]\ndata = ['a']\n[quantize]\ndata = ['a:2']\n")
    with pytest.raises(ValueError, match="shares"):  # int8 calibration images are no training
        load_build(config)
