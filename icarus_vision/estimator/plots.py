"""Plot of the estimator's error against the distance to the gate (PNG, written atomically)."""

from __future__ import annotations

import io
import os

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from icarus_vision.fileio import atomic_write_bytes  # noqa: E402


def plot_error_vs_distance(
    path: str | os.PathLike, dist: np.ndarray, err: np.ndarray, title: str = ""
) -> None:
    """Scatter of per-frame error against distance, with the binned median and 95th percentile.

    Args:
        dist: (F,) ground-truth distance from the drone to the next gate, m.
        err: (F,) norm of the error of the estimated relative position, m.
    """
    dist, err = np.asarray(dist, float), np.asarray(err, float)
    fig, ax = plt.subplots(figsize=(7, 4.5))
    ax.scatter(dist, np.maximum(err, 1e-4), s=6, alpha=0.4, color="tab:blue", label="frames")
    if len(dist):
        edges = np.arange(0.0, max(float(dist.max()), 1.0) + 1.0, 1.0)
        mids, med, p95 = [], [], []
        for lo, hi in zip(edges[:-1], edges[1:], strict=True):
            m = (dist >= lo) & (dist < hi)
            if m.sum() >= 3:
                mids.append(0.5 * (lo + hi))
                med.append(np.median(err[m]))
                p95.append(np.percentile(err[m], 95))
        ax.plot(mids, med, "-o", color="tab:orange", label="median (1 m bins)")
        ax.plot(mids, p95, "--s", color="tab:red", label="95th percentile")
    ax.axvline(5.0, color="grey", lw=0.8, ls=":")
    ax.set_yscale("log")
    ax.set_xlabel("distance to the next gate [m]")
    ax.set_ylabel("relative position error [m]")
    ax.set_title(title or "estimator error vs distance")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(loc="upper left", fontsize=8)
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110)
    plt.close(fig)
    atomic_write_bytes(path, buf.getvalue())
