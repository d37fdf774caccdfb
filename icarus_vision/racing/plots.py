"""Trajectory plot of a race: top view and altitude profile, path coloured by speed, gates drawn."""

from __future__ import annotations

import io
import os

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.collections import LineCollection  # noqa: E402

from icarus_vision.fileio import atomic_write_bytes  # noqa: E402
from icarus_vision.sim.track import Track  # noqa: E402


def _coloured_line(ax, x, y, c, vmax):
    pts = np.stack((x, y), axis=1)
    segs = np.stack((pts[:-1], pts[1:]), axis=1)
    lc = LineCollection(segs, cmap="viridis", norm=plt.Normalize(0, vmax), linewidths=2)
    lc.set_array(c[:-1])
    ax.add_collection(lc)
    return lc


def plot_trajectory(
    path: str | os.PathLike,
    track: Track,
    t,
    pos,
    speed,
    crash_point=None,
    title: str = "",
    ghost: tuple[np.ndarray, np.ndarray] | None = None,
) -> None:
    """Write a PNG: top view (x, y) and altitude against time, path coloured by speed.

    Args:
        t: (T,) s; pos: (T, 3) world positions; speed: (T,) m/s.
        crash_point: (3,) where the drone crashed, marked with a red cross, or None.
        ghost: the time-optimal plan as (t (M,) s, pos (M, 3)), drawn dashed, or None.
    """
    t, pos, speed = np.asarray(t), np.asarray(pos), np.asarray(speed)
    vmax = max(float(speed.max()), 1e-3)
    fig, (ax_top, ax_alt) = plt.subplots(
        1, 2, figsize=(12, 5), gridspec_kw={"width_ratios": [1.3, 1]}
    )
    lc = _coloured_line(ax_top, pos[:, 0], pos[:, 1], speed, vmax)
    for i, g in enumerate(track.gates):
        c = np.asarray(g.pos)
        half = g.size / 2 + g.frame_width
        d = np.array([-np.sin(g.yaw), np.cos(g.yaw)]) * half
        ax_top.plot(
            [c[0] - d[0], c[0] + d[0]], [c[1] - d[1], c[1] + d[1]], color="tab:orange", lw=4
        )
        ax_top.annotate(
            "",
            c[:2] + 0.8 * g.normal[:2],
            c[:2],
            arrowprops={"arrowstyle": "->", "color": "tab:orange"},
        )
        ax_top.text(c[0], c[1] + 0.4, str(i), fontsize=8, ha="center")
    if ghost is not None:
        gt, gp = np.asarray(ghost[0]), np.asarray(ghost[1])
        label = f"time-optimal plan ({gt[-1]:.2f} s)"
        ax_top.plot(gp[:, 0], gp[:, 1], "--", color="0.45", lw=1.2, label=label)
        ax_alt.plot(gt, gp[:, 2], "--", color="0.45", lw=1.2, label=label)
        ax_alt.legend(loc="best", fontsize=8)
    ax_top.plot(*track.start_pos[:2], "k^", label="start")
    if crash_point is not None:
        ax_top.plot(crash_point[0], crash_point[1], "rx", ms=14, mew=3, label="crash")
        ax_alt.plot(t[-1], crash_point[2], "rx", ms=14, mew=3)
    ax_top.set_aspect("equal")
    ax_top.autoscale()
    ax_top.set_xlabel("x [m]")
    ax_top.set_ylabel("y [m]")
    ax_top.legend(loc="best", fontsize=8)
    ax_top.set_title(title or track.name)
    _coloured_line(ax_alt, t, pos[:, 2], speed, vmax)
    ax_alt.autoscale()
    ax_alt.set_xlabel("time [s]")
    ax_alt.set_ylabel("altitude [m]")
    ax_alt.grid(alpha=0.3)
    fig.colorbar(lc, ax=[ax_top, ax_alt], label="speed [m/s]", shrink=0.8)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=100)
    plt.close(fig)
    atomic_write_bytes(path, buf.getvalue())
