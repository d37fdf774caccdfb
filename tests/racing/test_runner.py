from __future__ import annotations

import json

from icarus_vision.racing.report import REPORT_FIELDS, validate_report
from icarus_vision.racing.runner import run_race


def test_race_single_gate_report_has_every_field(backend):
    res = run_race("single-gate", backend=backend, seed=0)
    r = res.report
    validate_report(r)
    assert set(r) == set(REPORT_FIELDS)
    assert r["finished"] and r["gates_passed"] == r["gates_total"] == 1
    assert r["lap_times_s"] and r["total_time_s"] == r["lap_times_s"][0]
    assert r["realtime_factor"] > 1
    json.dumps(r, allow_nan=False)  # standard JSON
    assert res.pos.shape == (len(res.t), 3)


def test_laps_override_counts_passages():
    r = run_race("single-gate", laps=2, backend="batched").report
    assert r["laps"] == 2 and r["gates_total"] == 2
