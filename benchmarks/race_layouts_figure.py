"""Draw a sheet of race layouts (top view, gate heights as colour) for the docs.

.venv/bin/python benchmarks/race_layouts_figure.py [--difficulty 1.0] [--seed0 0] [--png docs/race_layouts.png]
"""

from __future__ import annotations

import argparse
import io

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from icarus_vision.fileio import atomic_write_bytes  # noqa: E402
from icarus_vision.sim.race_layouts import race_track, track_motifs  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--difficulty", type=float, default=1.0)
    ap.add_argument("--seed0", type=int, default=0)
    ap.add_argument("--png", default="docs/race_layouts.png")
    args = ap.parse_args()
    fig, axes = plt.subplots(2, 4, figsize=(16, 8))
    for k, ax in enumerate(axes.ravel()):
        seed = args.seed0 + k
        track = race_track(10, seed, difficulty=args.difficulty)
        pts = np.array([track.start_pos, *(g.pos for g in track.passages)])
        ax.plot(pts[:, 0], pts[:, 1], ":", color="0.6", lw=1)
        for i, g in enumerate(track.passages):
            c = np.asarray(g.pos)
            half = (g.size / 2 + g.frame_width) * np.array([-np.sin(g.yaw), np.cos(g.yaw)])
            colour = plt.cm.plasma(min(c[2] / 6.0, 1.0))
            ax.plot(
                [c[0] - half[0], c[0] + half[0]],
                [c[1] - half[1], c[1] + half[1]],
                color=colour,
                lw=4,
            )
            ax.annotate(
                "",
                c[:2] + 1.2 * g.normal[:2],
                c[:2],
                arrowprops={"arrowstyle": "->", "color": colour},
            )
            ax.text(c[0] + 0.3, c[1] + 0.3, str(i), fontsize=7)
        ax.plot(*track.start_pos[:2], "k^")
        motifs = ", ".join(sorted(track_motifs(track))) or "plain"
        ax.set_title(
            f"seed {seed}: {motifs}" + (f" ({track.laps} laps)" if track.laps > 1 else ""),
            fontsize=9,
        )
        ax.set_aspect("equal")
        ax.tick_params(labelsize=7)
    sm = plt.cm.ScalarMappable(cmap="plasma", norm=plt.Normalize(0, 6))
    fig.colorbar(sm, ax=axes, label="gate height [m]", shrink=0.6)
    fig.suptitle(
        f"race_track(10, seed, difficulty={args.difficulty:g}): gates as bars, arrows the passage direction"
    )
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=80)
    atomic_write_bytes(args.png, buf.getvalue())


if __name__ == "__main__":
    main()
