"""Make the README's animation: the default race with the shipped models, FPV beside the top view.

    .venv/bin/python tools/race_gif.py [--track grand-prix] [--seed 0] [--out docs/race.gif]

Plans the track first (cached) so that the top view shows the time-optimal ghost, flies `race`
with the CNN in the loop, and writes every third camera frame at half size as a looping GIF.
"""

from __future__ import annotations

import argparse
import io

import cv2
import numpy as np

from icarus_vision.fileio import atomic_write_bytes
from icarus_vision.planning.command import run_plan
from icarus_vision.racing.runner import run_race


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--track", default="grand-prix")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--every", type=int, default=3, help="keep every Nth camera frame")
    ap.add_argument("--scale", type=float, default=0.5)
    ap.add_argument("--out", default="docs/race.gif")
    args = ap.parse_args()
    import imageio.v2 as imageio

    run_plan(args.track)
    result = run_race(args.track, seed=args.seed, video=True)
    frames = [
        cv2.resize(f, None, fx=args.scale, fy=args.scale, interpolation=cv2.INTER_AREA)
        for f in result.video[:: args.every]
    ]
    frames += [frames[-1]] * 10  # hold the last frame before looping
    buf = io.BytesIO()
    fps = 30.0 / args.every
    imageio.mimsave(buf, [np.asarray(f) for f in frames], format="GIF", duration=1.0 / fps, loop=0)
    atomic_write_bytes(args.out, buf.getvalue())
    r = result.report
    print(f"{args.out}: {len(frames)} frames, {len(buf.getvalue()) / 1e6:.1f} MB; "
          f"{r['policy']} finished={r['finished']} lap={r['lap_times_s']}")  # fmt: skip


if __name__ == "__main__":
    main()
