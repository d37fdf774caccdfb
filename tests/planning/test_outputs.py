"""Cache, CSV, plot and the run_plan entry point (files only under tmp_path)."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np

from icarus_vision.planning import (
    format_summary,
    load_cached,
    plan,
    plan_key,
    plan_path,
    plan_time_for_race,
    plot_plan,
    run_plan,
    save_plan_csv,
)
from icarus_vision.planning.cache import save_cached
from icarus_vision.planning.io import CSV_COLUMNS


def test_cache_round_trip(straight_plan, straight_track, quad, tmp_path):
    assert load_cached(straight_track, quad, tmp_path) is None
    path = save_cached(straight_plan, straight_track, quad, tmp_path)
    assert path == plan_path(straight_track, quad, tmp_path) and path.is_file()
    assert [p.name for p in tmp_path.iterdir()] == [path.name]  # no temporary left behind
    hit = load_cached(straight_track, quad, tmp_path, nodes_per_gate=straight_plan.nodes_per_gate)
    assert hit is not None and hit.time_optimal_s == straight_plan.time_optimal_s
    np.testing.assert_array_equal(hit.pos, straight_plan.pos)
    assert load_cached(straight_track, quad, tmp_path, nodes_per_gate=7) is None
    assert plan_time_for_race(straight_track, quad, tmp_path) == straight_plan.time_optimal_s
    # plan() returns the cached result without solving
    again = plan(
        straight_track, quad, nodes_per_gate=straight_plan.nodes_per_gate, cache_dir=tmp_path
    )
    assert again.solve_time_s == straight_plan.solve_time_s
    # a corrupt file is treated as missing
    path.write_bytes(b"not a zip")
    assert load_cached(straight_track, quad, tmp_path) is None


def test_key_depends_on_physics_not_names(straight_track, quad):
    k = plan_key(straight_track, quad)
    assert plan_key(replace(straight_track, name="other"), replace(quad, name="x")) == k
    assert plan_key(straight_track, replace(quad, mass=0.6)) != k
    assert plan_key(straight_track.with_laps(2), quad) != k


def test_csv_and_plot(straight_plan, straight_track, quad, tmp_path):
    csv = save_plan_csv(straight_plan, tmp_path / "plan.csv")
    lines = csv.read_text().splitlines()
    assert lines[0].split(",") == CSV_COLUMNS
    assert len(lines) == len(straight_plan.t) + 1
    assert lines[-1].split(",")[-1] == "0"  # the last node is passage 0
    png = plot_plan(
        straight_plan, tmp_path / "plan.png", track=straight_track, thrust_max=quad.thrust_max
    )
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_run_plan_writes_outputs(straight_plan, straight_track, quad, tmp_path):
    save_cached(straight_plan, straight_track, quad, tmp_path)  # reuse: no second solve
    summary = run_plan(straight_track, quad, json_path=tmp_path / "p.json", out_dir=tmp_path)
    data = json.loads((tmp_path / "p.json").read_text())
    for key in (
        "track",
        "quad",
        "laps",
        "time_optimal_s",
        "point_mass_s",
        "solver_status",
        "solve_time_s",
    ):
        assert key in data
    assert data["cached"] is True and summary["track"] == "straight"
    assert (tmp_path / summary["csv"]).is_file() and (tmp_path / summary["plot"]).is_file()
    assert "minimum time" in format_summary(summary)
    assert "warning" not in format_summary(summary)
    assert "touches gate bars" in format_summary({**summary, "bar_contact_s": 0.05})
