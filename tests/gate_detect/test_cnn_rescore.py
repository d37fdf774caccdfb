"""The detector's fourth stage: features, labels, training, checkpoints, the detector using it."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from icarus_vision.gate_detect import make_detector
from icarus_vision.gate_detect.cnn import CnnDetector
from icarus_vision.gate_detect.cnn import rescore_train as rt
from icarus_vision.gate_detect.cnn.checkpoint import (
    load_checkpoint,
    load_rescorer,
    save_checkpoint,
    save_rescorer,
)
from icarus_vision.gate_detect.cnn.decode import DecodeConfig
from icarus_vision.gate_detect.cnn.model import CornerNet
from icarus_vision.gate_detect.cnn.refine import RefineConfig, RefineNet
from icarus_vision.gate_detect.cnn.rescore import (
    FEATURES,
    RescoreConfig,
    RescoreNet,
    features,
    labels,
)
from icarus_vision.gate_detect.cnn.zoom import ZoomConfig, ZoomNet

from .conftest import QUAD, TINY_MODEL, facing_box, gate_image

SIZE = (320, 240)
VISIBLE = np.full(4, 2)


def _features(refined, zoomed, prob=0.9, stage=0.8):
    n = len(refined)
    return features(np.full(n, prob), np.full(n, stage), refined, zoomed, SIZE)


def test_features_of_a_facing_square_say_square_unmoved_and_away_from_the_edge():
    box = facing_box(40, 40, 160)[None]
    f = dict(zip(FEATURES, _features(box, box)[0], strict=True))
    assert f["skew_zoom"] < 1e-6 and f["cos_zoom"] < 1e-6 and f["zoom_shift_max"] == 0.0
    assert f["log_side"] == pytest.approx(np.log(40)) and f["log_side_ratio"] == pytest.approx(0)
    assert f["border_px"] == pytest.approx(50.0)  # clipped: 100 px from the top
    assert f["logit_refiner"] == pytest.approx(np.log(9))


def test_features_see_a_non_square_opening_and_a_moved_corner():
    box = facing_box(60, 36, 160)[None]
    moved = box.copy()
    moved[0, 2, 0] += 6.0
    f = dict(zip(FEATURES, _features(moved, box)[0], strict=True))
    assert f["skew_zoom"] == pytest.approx(np.log(60 / 36), abs=0.02)
    assert f["zoom_shift_max"] == pytest.approx(6.0 / 48.0)
    assert f["zoom_shift_mean"] == pytest.approx(1.5 / 48.0)


def test_labels_follow_eval_detectors_matching_rule_for_every_labelled_gate():
    gate = facing_box(40, 40, 160)
    small = facing_box(12, 12, 60)
    cut = facing_box(40, 40, 10)  # partly outside the frame: not counted
    cut_vis = np.array([1 if x >= 0 else 0 for x in cut[:, 0]])
    truth = [(gate, VISIBLE, 5.0), (small, VISIBLE, 9.0), (cut, cut_vis, 5.0)]
    cands = np.stack([gate + 3.0, gate + 12.0, small, cut + 1.0, facing_box(40, 40, 260)])
    assert labels(cands, truth).tolist() == [1, 0, 1, 1, 0]


def test_numpy_probabilities_are_the_networks():
    torch.manual_seed(0)
    cfg = RescoreConfig(hidden=(8, 4), mean=tuple(np.arange(12.0)), std=tuple(np.ones(12) * 2))
    net = RescoreNet(cfg).eval()
    x = np.random.default_rng(0).normal(size=(7, len(FEATURES))) * 5
    with torch.no_grad():
        ref = torch.sigmoid(net(torch.tensor(x, dtype=torch.float64).float())).numpy()
    np.testing.assert_allclose(net.probabilities(x), ref, atol=1e-5)


def test_fit_learns_a_separable_rule_and_is_reproducible():
    rng = np.random.default_rng(1)
    x = rng.normal(size=(3000, len(FEATURES)))
    y = (x[:, 0] - 2 * x[:, 3] > 0).astype(int)
    image = np.arange(3000) // 3
    cfg = rt.RescoreTrainConfig(epochs=8, seed=2, batch_size=64)
    net, history = rt.fit(x, y, image, RescoreConfig(hidden=(16,)), cfg)
    assert history[-1]["held_out_loss"] < 0.5 * history[0]["held_out_loss"]
    assert history[-1]["held_out_accuracy"] > 0.95
    again, _ = rt.fit(x, y, image, RescoreConfig(hidden=(16,)), cfg)
    np.testing.assert_array_equal(net.probabilities(x[:50]), again.probabilities(x[:50]))


def _detector(folder, decode: DecodeConfig = DecodeConfig()):
    torch.manual_seed(0)
    refiner = RefineNet(RefineConfig(patch=16, margin=4, threshold=0.0)).eval()
    zoom = ZoomNet(ZoomConfig(patch=24, widths=(4, 8, 8, 8), hidden=16, min_side_px=10)).eval()
    return save_checkpoint(folder, CornerNet(TINY_MODEL).eval(), decode, {}, refiner, None, zoom)


def test_save_load_round_trip_and_bad_files_name_the_file(tmp_path):
    det = _detector(tmp_path / "ck")
    torch.manual_seed(3)
    net = RescoreNet(RescoreConfig(hidden=(8,), threshold=0.3)).eval()
    save_rescorer(det, net, {"n": 1})
    _, _, meta = load_checkpoint(det)
    loaded = load_rescorer(det, meta)
    x = np.random.default_rng(0).normal(size=(5, len(FEATURES)))
    assert loaded.cfg == net.cfg and meta["rescore_training"] == {"n": 1}
    np.testing.assert_array_equal(loaded.probabilities(x), net.probabilities(x))
    (det / "rescore.safetensors").write_bytes(b"garbage")
    with pytest.raises(ValueError, match="rescore.safetensors"):
        make_detector(f"cnn:{det}")
    (det / "rescore.safetensors").unlink()
    with pytest.raises(FileNotFoundError, match="rescore.safetensors"):
        make_detector(f"cnn:{det}")


def test_saving_the_networks_again_drops_the_rescorer_they_no_longer_match(tmp_path):
    det = _detector(tmp_path / "ck")
    save_rescorer(det, RescoreNet(), {})
    _detector(tmp_path / "ck")
    assert not (det / "rescore.safetensors").exists()
    assert "rescore" not in json.loads((det / "detector.json").read_text())


def test_a_rescorer_needs_a_refiner_and_a_zoom_stage():
    with pytest.raises(ValueError, match="rescorer needs"):
        CnnDetector(CornerNet(TINY_MODEL), rescorer=RescoreNet())


class Constant(RescoreNet):
    """A rescorer that answers ``p`` for every candidate."""

    def __init__(self, p: float, threshold: float) -> None:
        super().__init__(RescoreConfig(threshold=threshold))
        self.p = p

    def probabilities(self, x):
        return np.full(len(x), self.p)


def test_the_detector_reports_what_the_rescorer_passes(tmp_path, monkeypatch):
    det = CnnDetector.load(_detector(tmp_path / "ck"), backend="torch")
    img = gate_image()
    quads = np.stack([QUAD, QUAD + 0.5, QUAD + 100.0])  # two overlap; the last leaves the frame
    monkeypatch.setattr(det, "_candidates", lambda im, o, s: (
        np.array([0.9, 0.8, 0.7]), np.ones(3), quads, quads))  # fmt: skip
    det.rescorer = Constant(0.6, threshold=0.5)
    found = det.detect(img)
    assert len(found) == 1 and found[0].score == pytest.approx(0.6)
    np.testing.assert_allclose(found[0].corners, QUAD)
    det.rescorer = Constant(0.4, threshold=0.5)
    assert det.detect(img) == []


def test_min_score_keeps_only_the_gates_scored_at_least_it(tmp_path, monkeypatch):
    det = CnnDetector.load(_detector(tmp_path / "ck"), backend="torch", min_score=0.7)
    assert det.min_score == 0.7
    img = gate_image()
    quads = np.stack([QUAD, QUAD + 0.5])
    monkeypatch.setattr(det, "_candidates", lambda im, o, s: (
        np.array([0.9, 0.8]), np.ones(2), quads, quads))  # fmt: skip
    det.rescorer = Constant(0.6, threshold=0.5)
    assert det.detect(img) == []  # passed by the rescorer, under min_score
    det.min_score = 0.55
    assert [d.score for d in det.detect(img)] == [pytest.approx(0.6)]
    det.min_score = None
    assert len(det.detect(img)) == 1
    with pytest.raises(ValueError, match="min_score"):
        CnnDetector.load(_detector(tmp_path / "ck2"), backend="torch", min_score=1.5)
    # reachable by name, as the commands build it; a detector without the setting says so
    assert make_detector(f"cnn:{tmp_path / 'ck'}", min_score=0.9).min_score == 0.9
    with pytest.raises(ValueError, match="min_score"):
        make_detector("opencv", min_score=0.9)


def test_train_rescorer_writes_a_detector_that_loads_and_reuses_its_table(
    tiny_dataset, tmp_path, monkeypatch
):
    from icarus_vision.gate_detect.cnn.data import load_split, read_rgb

    # An untrained detector proposes nothing useful: each image's labelled gates, a little off,
    # and a quadrilateral on nothing stand in for its candidates.
    truth = {}
    for split in ("train", "val"):
        s = load_split(tiny_dataset, split)
        for path, gates in zip(s.files, s.gates, strict=True):
            truth[read_rgb(path).tobytes()] = [g.corners for g in gates
                                               if np.isfinite(g.corners).all()]  # fmt: skip

    def candidate_table(self, image):
        quads = np.stack([*truth[image.tobytes()], facing_box(20, 20, 30, 30)]) + 0.5
        n = len(quads)
        return features(np.full(n, 0.5), np.full(n, 0.5), quads, quads, (160, 120)), quads

    monkeypatch.setattr(CnnDetector, "candidate_table", candidate_table)
    det = _detector(tmp_path / "ck")
    cfg = rt.RescoreTrainConfig(epochs=2)
    logs = []
    out, history = rt.train_rescorer(det, [tiny_dataset], tmp_path / "r", ["train", "val"],
                                     RescoreConfig(hidden=(4,)), cfg, progress=False,
                                     log=logs.append, backend="torch")  # fmt: skip
    assert [h["epoch"] for h in history] == [1, 2]
    meta = json.loads((out / "detector.json").read_text())
    assert meta["rescore"]["hidden"] == [4] and meta["rescore_training"]["splits"] == [
        "train",
        "val",
    ]
    table = np.load(out / "candidates.npz")
    assert set(table["y"].tolist()) >= {0, 1}
    d = make_detector(f"cnn:{out}")
    assert d.rescorer is not None
    assert isinstance(d.detect(gate_image()[:120, :160].copy()), list)
    rt.train_rescorer(det, [tiny_dataset], tmp_path / "r", ["train", "val"],
                      RescoreConfig(hidden=(4,)), cfg, progress=False, log=logs.append,
                      backend="torch")  # fmt: skip
    assert any("reusing" in line for line in logs)


def test_train_rescorer_interrupted_while_reading_continues_from_its_parts(
    tiny_dataset, tmp_path, monkeypatch
):
    calls, stop = [], [5]

    def candidate_table(self, image):
        calls.append(1)
        if len(calls) == stop[0]:
            raise KeyboardInterrupt
        quads = np.stack([facing_box(20, 20, 40 + len(calls), 40), facing_box(30, 30, 100, 60)])
        return features(np.full(2, 0.5), np.full(2, 0.5), quads, quads, (160, 120)), quads

    monkeypatch.setattr(CnnDetector, "candidate_table", candidate_table)
    monkeypatch.setattr(rt, "PART", 3)
    det = _detector(tmp_path / "ck")
    kw = {"net_cfg": RescoreConfig(hidden=(4,)), "cfg": rt.RescoreTrainConfig(epochs=1),
          "progress": False, "log": lambda s: None, "backend": "torch"}  # fmt: skip
    with pytest.raises(KeyboardInterrupt):
        rt.train_rescorer(det, [tiny_dataset], tmp_path / "r", ["train"], **kw)
    assert sorted(p.name for p in (tmp_path / "r" / rt.PARTS).iterdir()) == ["00000.npz"]
    calls.clear()
    stop[0] = 0  # no second interruption
    rt.train_rescorer(det, [tiny_dataset], tmp_path / "r", ["train"], **kw)
    assert len(calls) == 8 - 3  # the first part was read back, not read again
    assert not (tmp_path / "r" / rt.PARTS).exists()
    table = np.load(tmp_path / "r" / "candidates.npz")
    assert table["image"].tolist() == [i for i in range(8) for _ in range(2)]
