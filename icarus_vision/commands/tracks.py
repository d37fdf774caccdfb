"""`icarus-vision tracks`: list the built-in tracks."""

from __future__ import annotations

from rich.table import Table

from icarus_vision.cli import app, console, user_errors


@app.command("tracks")
@user_errors
def tracks_cmd() -> None:
    """List the built-in tracks."""
    from icarus_vision.sim.builtin import BUILTIN_TRACKS, DEFAULT_TRACK, builtin_track

    table = Table(title="built-in tracks")
    for col in ("name", "gates", "laps", "length [m]", "height [m]"):
        table.add_column(col)
    import numpy as np

    for name in BUILTIN_TRACKS:
        t = builtin_track(name)
        pts = np.array([t.start_pos, *(g.pos for g in t.gates)])
        length = float(np.linalg.norm(np.diff(pts, axis=0), axis=1).sum())
        z = pts[1:, 2]
        label = f"{name} (default)" if name == DEFAULT_TRACK else name
        table.add_row(
            label, str(len(t.gates)), str(t.laps), f"{length:.1f}", f"{z.min():.1f}–{z.max():.1f}"
        )
    console.print(table)
