"""Infeasible tracks and solver failures raise PlanError with a status, and write nothing."""

from __future__ import annotations

import pytest

from icarus_vision.planning import PlanError, plan, run_plan
from icarus_vision.planning.solver import SolverConfig
from icarus_vision.sim.track import Gate, Track


def test_empty_window_is_presolve_infeasible(straight_track, quad, tmp_path):
    with pytest.raises(PlanError) as e:
        plan(straight_track, quad, tol=0.5, cache_dir=tmp_path)
    assert e.value.status == "Presolve_Infeasible"
    assert "gate 0" in str(e.value)
    assert list(tmp_path.iterdir()) == []


def test_window_outside_bounds_is_presolve_infeasible(quad, tmp_path):
    track = Track(
        name="ceiling",
        gates=(Gate(pos=(5.0, 0.0, 3.0), size=0.2),),  # window z 2.9..3.1, centre z <= 2.85
        start_pos=(0.0, 0.0, 1.0),
        bounds_min=(-5.0, -5.0, 0.0),
        bounds_max=(10.0, 5.0, 3.0),
    )
    with pytest.raises(PlanError) as e:
        plan(track, quad, tol=0.0, cache_dir=tmp_path)
    assert e.value.status == "Presolve_Infeasible"
    assert list(tmp_path.iterdir()) == []


def test_solver_failure_raises_with_status(straight_track, quad, tmp_path):
    with pytest.raises(PlanError) as e:
        plan(straight_track, quad, cache_dir=tmp_path, solver=SolverConfig(max_iter=3))
    assert e.value.status == "Maximum_Iterations_Exceeded"
    assert "Maximum_Iterations_Exceeded" in str(e.value)
    assert list(tmp_path.iterdir()) == []


def test_run_plan_failure_writes_no_json(straight_track, quad, tmp_path):
    out = tmp_path / "plans"
    with pytest.raises(PlanError):
        run_plan(straight_track, quad, json_path=tmp_path / "p.json", out_dir=out, tol=0.6)
    assert not (tmp_path / "p.json").exists()
    assert not out.exists() or list(out.iterdir()) == []


def test_bad_options(straight_track, quad):
    with pytest.raises(ValueError):
        plan(straight_track, quad, nodes_per_gate=1, cache_dir=None)
    with pytest.raises(ValueError):
        plan(straight_track, quad, tol=-0.1, cache_dir=None)
