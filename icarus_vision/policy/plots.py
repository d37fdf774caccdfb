"""Training curves: success rate and mean return against wall-clock time."""

from __future__ import annotations

import io
import os

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from icarus_vision.fileio import atomic_write_bytes  # noqa: E402


def plot_training_curves(
    runs: dict[str, list[dict]], path: str | os.PathLike, title: str = ""
) -> None:
    """Write a PNG with success rate (curriculum stage shaded) and mean return against wall-clock.

    Args:
        runs: label -> metrics rows (``metrics.json`` of a training run: wall_s, timesteps,
            num_gates, success_rate, mean_return).
    """
    fig, (ax_s, ax_r) = plt.subplots(1, 2, figsize=(12, 4.5))
    for label, rows in runs.items():
        if not rows:
            continue
        t = np.array([r["wall_s"] for r in rows]) / 60.0
        succ = np.array([r["success_rate"] for r in rows])
        ret = np.array([np.nan if r["mean_return"] is None else r["mean_return"] for r in rows])
        gates = np.array([r["num_gates"] for r in rows])
        (line,) = ax_s.plot(t, succ, label=label)
        for g in np.unique(gates):
            first = np.flatnonzero(gates == g)[0]
            ax_s.annotate(f"{g}g", (t[first], succ[first]), fontsize=7, color=line.get_color())
        ax_r.plot(t, ret, label=label, color=line.get_color())
    ax_s.axhline(0.8, color="grey", ls=":", lw=1)
    ax_s.set_xlabel("wall-clock [min]")
    ax_s.set_ylabel("success rate (last 100 episodes, current stage)")
    ax_s.set_ylim(-0.02, 1.02)
    ax_r.set_xlabel("wall-clock [min]")
    ax_r.set_ylabel("mean episode return")
    for ax in (ax_s, ax_r):
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    fig.suptitle(title)
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=100)
    plt.close(fig)
    atomic_write_bytes(path, buf.getvalue())
