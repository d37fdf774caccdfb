"""What ``icarus-vision plan`` does, callable from Python: plan (or reuse the cache) and write outputs."""

from __future__ import annotations

import os
from pathlib import Path

from icarus_vision.fileio import atomic_write_json
from icarus_vision.planning.cache import DEFAULT_CACHE_DIR, load_cached, plan_path
from icarus_vision.planning.geometry import default_tol
from icarus_vision.planning.io import plot_plan, save_plan_csv
from icarus_vision.planning.planner import plan
from icarus_vision.sim.builtin import resolve_track
from icarus_vision.sim.quad import QuadParams, load_quad
from icarus_vision.sim.track import Track


def run_plan(
    track: str | os.PathLike | Track | None,
    quad: str | os.PathLike | QuadParams | None = None,
    *,
    json_path: str | os.PathLike | None = None,
    out_dir: str | os.PathLike = DEFAULT_CACHE_DIR,
    nodes_per_gate: int = 20,
    tol: float | None = None,
    use_cache: bool = True,
) -> dict:
    """Plan the minimum-time trajectory of a track and write its cache file, CSV, plot and JSON.

    Args:
        track: built-in name, TOML path or Track (None: the default track).
        quad: quadrotor TOML path or QuadParams (None: the default quadrotor).
        json_path: where to write the summary JSON (None: not written).
        out_dir: folder of the cache and of ``<track>-<key>.csv`` / ``.png``.
        nodes_per_gate, tol: planner options (see ``plan``).
        use_cache: reuse a cached plan made with the same options.

    Returns:
        The ``plan --json`` fields (``PlanResult.summary``) plus ``cached`` (bool) and the written
        ``plan_file``, ``csv`` and ``plot`` paths (str).

    Raises:
        TrackError / QuadError: bad track or quadrotor file.
        ValueError: bad planner option.
        PlanError: infeasible track or solver failure (``.status``); no file is written then.
    """
    trk = resolve_track(track)
    q = quad if isinstance(quad, QuadParams) else (load_quad(quad) if quad else QuadParams())
    tol_m = default_tol(q) if tol is None else float(tol)
    result = (
        load_cached(trk, q, out_dir, nodes_per_gate=nodes_per_gate, tol=tol_m)
        if use_cache
        else None
    )
    cached = result is not None
    if result is None:
        result = plan(
            trk, q, nodes_per_gate=nodes_per_gate, tol=tol_m, cache_dir=out_dir, use_cache=False
        )
    base = plan_path(trk, q, out_dir)
    csv = save_plan_csv(result, base.with_suffix(".csv"))
    png = plot_plan(result, base.with_suffix(".png"), track=trk, thrust_max=q.thrust_max)
    summary = {
        **result.summary(),
        "cached": cached,
        "plan_file": str(base),
        "csv": str(csv),
        "plot": str(png),
    }
    if json_path is not None:
        atomic_write_json(json_path, summary)
    return summary


def format_summary(summary: dict) -> str:
    """Human-readable lines for the terminal from ``run_plan``'s dictionary."""
    ratio = summary["time_optimal_s"] / summary["point_mass_s"]
    src = "cache" if summary["cached"] else f"solved in {summary['solve_time_s']:.1f} s"
    lines = (
        f"track {summary['track']} ({summary['laps']} lap(s)), quad {summary['quad']}",
        f"minimum time      {summary['time_optimal_s']:.3f} s",
        f"point-mass bound  {summary['point_mass_s']:.3f} s  (ratio {ratio:.3f})",
        f"solver            {summary['solver_status']}, {src}",
        f"trajectory        {summary['csv']}",
        f"plot              {summary['plot']}",
    )
    if summary.get("bar_contact_s", 0.0) > 0:
        lines += (
            f"warning           the path touches gate bars for {summary['bar_contact_s']:.3f} s "
            "(only the passages are constrained; the time is optimistic)",
        )
    return "\n".join(lines)


def plan_time_for_race(
    track: Track, quad: QuadParams, cache_dir: str | os.PathLike = DEFAULT_CACHE_DIR
) -> float | None:
    """The cached minimum time of (track, quad) for a race report, or None when no plan exists."""
    hit = load_cached(track, quad, Path(cache_dir))
    return None if hit is None else hit.time_optimal_s
