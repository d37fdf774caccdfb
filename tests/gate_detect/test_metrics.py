"""Matching and metrics on known inputs; eval_detector and its error model on a tiny dataset."""

from __future__ import annotations

import hashlib
import json

import numpy as np
import pytest

from icarus_vision.gate_detect import Detector, GateDetection, register_detector
from icarus_vision.gate_detect.cnn.data import load_split, read_rgb
from icarus_vision.gate_detect.evaluate import eval_detector
from icarus_vision.gate_detect.metrics import confidence, evaluate_image, match, summarize
from icarus_vision.policy.perception_noise import ErrorModel

SQUARE = np.array([[100.0, 100.0], [140.0, 100.0], [140.0, 140.0], [100.0, 140.0]])  # side 40
VIS = np.array([2, 2, 2, 2])


def test_match_is_greedy_by_score_and_one_to_one():
    a, b = SQUARE, SQUARE + 200
    m = match([a + 1.0, a + 3.0, b + 20.0], [0.5, 0.9, 0.8], [a, b])
    assert m == {1: (0, pytest.approx(np.hypot(3, 3)))}  # 0 loses a to 1; b + 20 is too far
    assert match([a + [6.0, 8.0]], [1.0], [a]) == {0: (0, pytest.approx(10.0))}  # <= 0.25 * 40
    assert match([a + [6.0, 8.1]], [1.0], [a]) == {}
    assert match([a + 8.0], [1.0], [a + np.nan]) == {}


def test_known_errors_give_known_figures():
    truth = [(SQUARE, VIS, 5.0), (SQUARE + 150, VIS, 6.0), (SQUARE * 0.3, VIS, 20.0)]  # 3rd: 12 px
    pred = [(SQUARE + [0.6, 0.8], 0.9), (np.array([[0, 0], [30, 0], [30, 30], [0, 30.0]]) + 300, 0.8),
            (SQUARE * 0.3 + 1, 0.7)]  # fmt: skip
    gts, preds = evaluate_image(pred, truth, min_gate_px=20)
    assert [p["status"] for p in preds] == ["tp", "fp", "ignored"]
    s = summarize(gts, preds, 20)
    assert s["gates"] == 2 and s["precision"] == 0.5 and s["recall"] == 0.5
    assert s["corner_error_px"] == {"mean": 1.0, "median": 1.0}
    assert s["pck"] == {"2px": 0.5, "5px": 0.5}  # the missed gate's corners count as failures


def test_occluded_and_partial_gates_are_ignored():
    hidden = np.array([2, 1, 1, 2])
    outside = np.array([2, 2, 2, 0])
    gts, preds = evaluate_image([], [(SQUARE, hidden, 5.0), (SQUARE, outside, 5.0)], 20)
    assert summarize(gts, preds, 20)["gates"] == 0


def _images(errors_px: list[float], misses: int, false_alarms: int) -> list:
    """One image per gate found with all corners ``error`` px off, one per missed gate, one per
    false alarm."""
    far = SQUARE + 150
    out = [evaluate_image([(SQUARE + [0.6 * e, 0.8 * e], 0.9)], [(SQUARE, VIS, 5.0)], 20)
           for e in errors_px]  # fmt: skip
    out += [evaluate_image([], [(SQUARE, VIS, 5.0)], 20) for _ in range(misses)]
    return out + [evaluate_image([(far, 0.5)], [], 20) for _ in range(false_alarms)]


def test_confidence_intervals_hold_the_figures_and_shrink_with_more_images():
    errors = [0.5, 1.0, 1.5, 3.0, 6.0] * 8
    images = _images(errors, 4, 6)
    small = confidence(images, 20, resamples=500)
    s = summarize(sum((g for g, _ in images), []), sum((p for _, p in images), []), 20)
    assert small["precision"][0] <= s["precision"] <= small["precision"][1] < 1.0
    assert small["recall"][0] <= s["recall"] <= small["recall"][1] < 1.0
    assert small["pck_5px"][0] <= s["pck"]["5px"] <= small["pck_5px"][1]
    assert small["corner_error_median_px"][0] <= 1.5 <= small["corner_error_median_px"][1]
    big = confidence(_images(errors * 10, 40, 60), 20, resamples=500)
    for k in ("precision", "recall", "pck_2px", "pck_5px"):
        assert big[k][1] - big[k][0] < 0.6 * (small[k][1] - small[k][0]), k
    assert confidence(images, 20, resamples=500) == small  # same seed, same intervals
    assert confidence(images, 20, resamples=500, seed=1) != small


def test_confidence_of_a_perfect_detector_is_a_point_and_bad_arguments_fail():
    c = confidence(_images([1.0] * 10, 0, 0), 20, resamples=50)
    assert c["precision"] == [1.0, 1.0] and c["pck_2px"] == [1.0, 1.0]
    assert c["corner_error_median_px"] == [pytest.approx(1.0)] * 2
    assert confidence(_images([], 3, 0), 20, resamples=50)["precision"] is None  # no detections
    with pytest.raises(ValueError, match="level"):
        confidence(_images([1.0], 0, 0), 20, level=1.5)
    with pytest.raises(ValueError, match="resamples"):
        confidence(_images([1.0], 0, 0), 20, resamples=0)


class TruthDetector(Detector):
    """Reports the true corners of a dataset shifted by (0.6, 0.8) px (error exactly 1 px)."""

    name = "truth"
    table: dict[str, list[np.ndarray]] = {}

    def _detect(self, image):
        key = hashlib.sha1(image.tobytes()).hexdigest()
        return [GateDetection(c + [0.6, 0.8], np.ones(4), 1.0) for c in self.table.get(key, [])]


@pytest.fixture
def truth_detector(tiny_dataset):
    split = load_split(tiny_dataset, "test")
    TruthDetector.table = {
        hashlib.sha1(read_rgb(f).tobytes()).hexdigest(): [
            g.corners for g in gates if np.isfinite(g.corners).all()
        ]
        for f, gates in zip(split.files, split.gates, strict=True)
    }
    register_detector("truth-test", lambda arg: TruthDetector())
    return "truth-test"


def test_eval_detector_on_shifted_truth(tiny_dataset, truth_detector, tmp_path):
    r = eval_detector(tiny_dataset, truth_detector, tmp_path / "r.json", min_gate_px=0)
    for key in ("detector", "images", "gates", "min_gate_px", "precision", "recall",
                "corner_error_px", "pck", "ms_per_frame", "by_distance"):  # fmt: skip
        assert key in r
    assert r["images"] == 4 and r["gates"] > 0
    assert "int8:" in r["cpu"]  # the machine its ms_per_frame were measured on
    assert r["precision"] == 1.0 and r["recall"] == 1.0
    assert r["corner_error_px"]["median"] == pytest.approx(1.0)
    assert r["pck"] == {"2px": 1.0, "5px": 1.0}
    assert r["confidence"]["recall"] == [1.0, 1.0] and r["confidence"]["resamples"] == 1000
    assert json.loads((tmp_path / "r.json").read_text())["gates"] == r["gates"]
    model = ErrorModel.load(tmp_path / "r.error_model.json")
    assert model.miss_rate == tuple(0.0 for _ in model.miss_rate)
    assert all(s > 0 for s in model.sigma_m)


def test_eval_detector_names_the_first_bad_image(tiny_dataset, tmp_path):
    import shutil

    copy = tmp_path / "ds"
    shutil.copytree(tiny_dataset, copy)
    test = json.loads((copy / "annotations" / "test.json").read_text())
    first, second = (copy / "images" / im["file_name"] for im in test["images"][:2])
    second.write_bytes(b"garbage")
    with pytest.raises(ValueError, match=second.name):
        eval_detector(copy, "opencv")
    first.unlink()
    with pytest.raises(FileNotFoundError, match=first.name):
        eval_detector(copy, "opencv")


def test_eval_detector_bad_arguments(tiny_dataset, tmp_path):
    with pytest.raises(FileNotFoundError, match="nowhere"):
        eval_detector(tmp_path / "nowhere", "opencv")
    with pytest.raises(ValueError, match="unknown detector"):
        eval_detector(tiny_dataset, "nosuch")
    with pytest.raises(ValueError, match="resamples"):
        eval_detector(tiny_dataset, "opencv", resamples=-1)


def test_pnp_centre_of_a_degenerate_quad_is_none():
    from icarus_vision.gate_detect.error_model import pnp_centre

    k = np.array([[160.0, 0, 159.5], [0, 160.0, 119.5], [0, 0, 1]])
    assert pnp_centre(np.full((4, 2), 100.0), k) is None
    t = pnp_centre(SQUARE, k)  # 40 px side at f = 160: 4 m away
    assert t is not None and t[2] == pytest.approx(4.0, rel=1e-3)
