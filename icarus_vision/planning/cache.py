"""On-disk cache of plans keyed by a hash of the (track, quadrotor) physics, written atomically.

File: ``<dir>/<track name>-<key>.npz`` holding the PlanResult arrays and its scalar fields (JSON).
The key covers what the optimum depends on (gates, start, laps, bounds; mass, thrust, rates, lag,
drag, radius) and the planner version, not names or the camera.
"""

from __future__ import annotations

import hashlib
import json
import re
import zipfile
from dataclasses import asdict, fields, replace
from pathlib import Path

import numpy as np

from icarus_vision.fileio import atomic_write_npz
from icarus_vision.planning.result import PlanResult
from icarus_vision.sim.quad import QuadParams
from icarus_vision.sim.track import Track

PLANNER_VERSION = 2
DEFAULT_CACHE_DIR = Path("runs/plans")
_ARRAYS = ("t", "pos", "vel", "quat", "thrust", "rates", "thrust_cmd", "rate_cmd", "gate_nodes")


def plan_key(track: Track, quad: QuadParams) -> str:
    """16-hex-digit hash of the track geometry and the quadrotor's dynamic parameters."""
    q = asdict(quad)
    q.pop("camera", None)
    q.pop("name", None)
    data = {
        "version": PLANNER_VERSION,
        "gates": [[list(g.pos), g.yaw_deg, g.size, g.frame_width] for g in track.gates],
        "start": [list(track.start_pos), track.start_yaw_deg],
        "laps": track.laps,
        "bounds": [list(track.bounds_min), list(track.bounds_max)],
        "quad": q,
    }
    blob = json.dumps(data, sort_keys=True, default=list).encode()
    return hashlib.sha256(blob).hexdigest()[:16]


def plan_path(track: Track, quad: QuadParams, cache_dir: str | Path = DEFAULT_CACHE_DIR) -> Path:
    """Cache file of (track, quad): ``<cache_dir>/<track name>-<key>.npz``."""
    safe = re.sub(r"[^A-Za-z0-9_.-]+", "_", track.name) or "track"
    return Path(cache_dir) / f"{safe}-{plan_key(track, quad)}.npz"


def save_cached(result: PlanResult, track: Track, quad: QuadParams, cache_dir: str | Path) -> Path:
    """Write ``result`` to the cache atomically; returns the file."""
    meta = {f.name: getattr(result, f.name) for f in fields(result) if f.name not in _ARRAYS}
    path = plan_path(track, quad, cache_dir)
    atomic_write_npz(
        path, meta=np.array(json.dumps(meta)), **{a: getattr(result, a) for a in _ARRAYS}
    )
    return path


def load_cached(
    track: Track,
    quad: QuadParams,
    cache_dir: str | Path = DEFAULT_CACHE_DIR,
    *,
    nodes_per_gate: int | None = None,
    tol: float | None = None,
) -> PlanResult | None:
    """The cached plan of (track, quad), or None (missing, unreadable, or other planner options).

    Args:
        nodes_per_gate, tol: when given, a cached plan made with other values is not returned.
    """
    path = plan_path(track, quad, cache_dir)
    if not path.is_file():
        return None
    try:
        with np.load(path, allow_pickle=False) as z:
            meta = json.loads(str(z["meta"]))
            arrays = {a: np.array(z[a]) for a in _ARRAYS}
        result = PlanResult(**meta, **arrays)
    except (OSError, EOFError, ValueError, KeyError, TypeError, zipfile.BadZipFile):
        return None
    if nodes_per_gate is not None and result.nodes_per_gate != nodes_per_gate:
        return None
    if tol is not None and abs(result.tol - tol) > 1e-12:
        return None
    return replace(result, track=track.name, quad=quad.name)
