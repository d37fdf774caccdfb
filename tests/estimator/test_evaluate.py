"""Closed loop: PyBullet + scripted pilot flying on the estimate, the oracle detector in the loop."""

from __future__ import annotations

import json

import pytest
from typer.testing import CliRunner

from icarus_vision.cli import app
from icarus_vision.estimator import EstimatorConfig, OdometryConfig
from icarus_vision.estimator.evaluate import evaluate_estimator

FIELDS = ("detector", "track", "frames", "detection_rate", "rel_gate_error_m", "within_5m")


def test_oracle_in_the_loop_matches_ground_truth():
    """Exact corners and exact odometry: the estimate is within a few centimetres."""
    r = evaluate_estimator(
        "three-gates", "oracle", 0, render=False, odometry=OdometryConfig(0, 0, 0, 0, 0, 0)
    )
    assert r["finished"] and r["gates_passed"] == r["gates_total"] == 3
    assert r["target_agreement"] > 0.98
    assert r["within_5m"]["median"] < 0.02 and r["within_5m"]["p95"] < 0.05
    assert r["detection_rate"] > 0.8  # frames with a gate in view; depends on the pilot's path
    for f in (*FIELDS, "ms_per_frame", "by_distance", "counts"):
        assert f in r
    json.dumps(r, allow_nan=False)


def test_deterministic_and_map_free():
    kw = dict(render=False, pixel_noise=1.0, config=EstimatorConfig(mode="map-free"))
    a = evaluate_estimator("three-gates", "oracle", 3, **kw)
    b = evaluate_estimator("three-gates", "oracle", 3, **kw)
    assert a["rel_gate_error_m"] == b["rel_gate_error_m"] and a["counts"] == b["counts"]
    assert a["finished"] and a["within_5m"]["median"] < 0.1


def test_unknown_detector_or_missing_weights_are_clear_errors():
    with pytest.raises(ValueError, match="unknown detector 'nosuch'"):
        evaluate_estimator("single-gate", "nosuch", render=False)
    with pytest.raises(FileNotFoundError, match="weights.safetensors"):
        evaluate_estimator("single-gate", "cnn:weights.safetensors", render=False)


def test_cli_writes_report_and_plot(tmp_path):
    out = tmp_path / "run"
    res = CliRunner().invoke(
        app,
        ["eval-estimator", "--track", "single-gate", "--pixel-noise", "0.5",
         "--json", str(tmp_path / "r.json"), "--out", str(out)],
    )  # fmt: skip
    assert res.exit_code == 0, res.output
    report = json.loads((tmp_path / "r.json").read_text())
    for f in (*FIELDS, "ms_per_frame"):
        assert f in report
    assert report["frames"] > 10 and report["track"] == "single-gate"
    assert (out / "report.json").exists()
    assert (out / "error_vs_distance.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_cli_errors_are_one_line():
    res = CliRunner().invoke(app, ["eval-estimator", "--detector", "nosuch"])
    assert res.exit_code == 1
    assert "unknown detector 'nosuch'" in res.output
    assert "Traceback" not in res.output
