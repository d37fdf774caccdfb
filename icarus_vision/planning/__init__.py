"""Time-optimal planning: the minimum lap time of the simulated quadrotor through a track's gates.

Public API:
    plan(track, quad, *, nodes_per_gate, tol, cache_dir) -> PlanResult   (raises PlanError)
    run_plan(track, quad, *, json_path, out_dir) -> dict                 (what the CLI calls)
    load_cached / plan_time_for_race                                     (for race reports)
    save_plan_csv, plot_plan, bang_bang_time
"""

from __future__ import annotations

from icarus_vision.planning.cache import DEFAULT_CACHE_DIR, load_cached, plan_key, plan_path
from icarus_vision.planning.command import format_summary, plan_time_for_race, run_plan
from icarus_vision.planning.io import plot_plan, save_plan_csv
from icarus_vision.planning.planner import plan
from icarus_vision.planning.point_mass import bang_bang_time
from icarus_vision.planning.result import PlanError, PlanResult

__all__ = [
    "DEFAULT_CACHE_DIR",
    "PlanError",
    "PlanResult",
    "bang_bang_time",
    "format_summary",
    "load_cached",
    "plan",
    "plan_key",
    "plan_path",
    "plan_time_for_race",
    "plot_plan",
    "run_plan",
    "save_plan_csv",
]
