"""Plan outputs: the trajectory as CSV and a four-panel plot (top view, altitude, speed, thrust)."""

from __future__ import annotations

import io
import os
from pathlib import Path

import numpy as np

from icarus_vision.fileio import atomic_write_bytes, atomic_write_text
from icarus_vision.planning.result import PlanResult
from icarus_vision.sim.track import Track

CSV_COLUMNS = (
    "t,x,y,z,vx,vy,vz,qx,qy,qz,qw,thrust,wx,wy,wz,thrust_cmd,wx_cmd,wy_cmd,wz_cmd,gate"
).split(",")


def plan_to_csv(result: PlanResult) -> str:
    """The trajectory as CSV text, one row per node.

    Columns: t (s); x, y, z (m, world); vx, vy, vz (m/s); qx, qy, qz, qw (body -> world); thrust (N,
    actual); wx, wy, wz (rad/s, actual body rates); thrust_cmd, wx_cmd, wy_cmd, wz_cmd (commands held
    from this node to the next; empty on the last row); gate (passage index made at this node, or
    empty).
    """
    gate_at = {int(n): i for i, n in enumerate(result.gate_nodes)}
    lines = [",".join(CSV_COLUMNS)]
    k_int = len(result.thrust_cmd)
    for k in range(len(result.t)):
        vals = [result.t[k], *result.pos[k], *result.vel[k], *result.quat[k], result.thrust[k]]
        vals += list(result.rates[k])
        row = [f"{v:.6g}" for v in vals]
        if k < k_int:
            row += [f"{v:.6g}" for v in (result.thrust_cmd[k], *result.rate_cmd[k])]
        else:
            row += ["", "", "", ""]
        row.append(str(gate_at[k]) if k in gate_at else "")
        lines.append(",".join(row))
    return "\n".join(lines) + "\n"


def save_plan_csv(result: PlanResult, path: str | os.PathLike) -> Path:
    """Write the trajectory CSV (``plan_to_csv``) atomically; returns the path."""
    atomic_write_text(path, plan_to_csv(result))
    return Path(path)


def plot_plan(
    result: PlanResult,
    path: str | os.PathLike,
    track: Track | None = None,
    thrust_max: float | None = None,
) -> Path:
    """Write a PNG with the top view, altitude, speed and thrust against time, atomically.

    Args:
        result: the plan.
        path: PNG file to write.
        track: when given, the gate openings are drawn in the top view.
        thrust_max: when given, T_max is drawn in the thrust panel, N.
    """
    from matplotlib.collections import LineCollection
    from matplotlib.figure import Figure  # no pyplot: no global state, no GUI backend

    speed = result.speed
    gt = result.t[result.gate_nodes]
    fig = Figure(figsize=(11, 8))
    axes = fig.subplots(2, 2)
    ax = axes[0, 0]
    seg = np.stack([result.pos[:-1, :2], result.pos[1:, :2]], axis=1)
    lc = LineCollection(seg, cmap="viridis", linewidths=2.0)
    lc.set_array(0.5 * (speed[:-1] + speed[1:]))
    ax.add_collection(lc)
    fig.colorbar(lc, ax=ax, label="speed (m/s)")
    if track is not None:
        for i, g in enumerate(track.gates):
            c = g.corners()
            ax.plot(c[:2, 0], c[:2, 1], "r-", lw=3)
            ax.annotate(str(i), g.pos[:2], textcoords="offset points", xytext=(6, 6), color="r")
    ax.plot(*result.pos[0, :2], "ko", label="start")
    ax.plot(*result.pos[result.gate_nodes, :2].T, "rx", label="passages")
    ax.set(xlabel="x (m)", ylabel="y (m)", title="top view", aspect="equal")
    ax.autoscale()
    ax.legend(loc="best", fontsize=8)
    panels = (
        (axes[0, 1], result.pos[:, 2], "altitude z (m)"),
        (axes[1, 0], speed, "speed (m/s)"),
        (axes[1, 1], result.thrust, "thrust (N)"),
    )
    for ax, y, label in panels:
        ax.plot(result.t, y, "b-")
        for tg in gt:
            ax.axvline(tg, color="r", lw=0.5, alpha=0.5)
        ax.set(xlabel="time (s)", ylabel=label)
        ax.grid(alpha=0.3)
    axes[1, 1].step(result.t[:-1], result.thrust_cmd, "g-", where="post", lw=0.8, label="command")
    if thrust_max is not None:
        axes[1, 1].axhline(thrust_max, color="k", ls="--", lw=0.8, label="T_max")
    axes[1, 1].legend(loc="best", fontsize=8)
    fig.suptitle(
        f"{result.track} / {result.quad}: {result.time_optimal_s:.3f} s "
        f"(point mass {result.point_mass_s:.3f} s)"
    )
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110)
    atomic_write_bytes(path, buf.getvalue())
    return Path(path)
