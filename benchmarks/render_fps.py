"""Rendering throughput of one PyBullet client (one core): labelled 320x240 frames per second.

Usage: ``python benchmarks/render_fps.py [--frames N] [--seed N] [--shadows] [--gloss K]
[--renderer tiny|egl]``.
A 10-gate random track with gates-v1 randomisation; poses on approach paths 1.5-10 m before a gate.
Reports render-only (renderer + ground/sky) and full (render + labels + sensor noise) rates;
``--shadows`` turns the light's shadows on (TinyRenderer's shadow map and the ground shadows),
``--gloss K`` a glossy floor of reflectivity K (a second, mirrored render where the floor is seen).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import time
from pathlib import Path

import numpy as np

from icarus_vision.render.labels import frame_labels
from icarus_vision.render.randomize import apply_sensor_noise, load_recipe, sample_visuals
from icarus_vision.render.scene import Gloss, Scene
from icarus_vision.sim.dynamics import rpy_to_quat
from icarus_vision.sim.random_track import random_track

RECIPE = Path(__file__).resolve().parents[1] / "datasets" / "gates-v1.toml"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=300)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--shadows", action="store_true", help="render every frame with shadows")
    ap.add_argument("--gloss", type=float, default=0.0, help="floor reflectivity (0: matte)")
    ap.add_argument("--renderer", choices=("tiny", "egl"), default="tiny")
    args = ap.parse_args()
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {sorted(os.sched_getaffinity(0))[0]})  # one core
    rng = np.random.default_rng(args.seed)
    recipe = load_recipe(RECIPE)
    track = random_track(10, seed=rng)
    vis = sample_visuals(recipe, rng, track)
    light = dataclasses.replace(vis.lighting, shadows=args.shadows)
    style = dataclasses.replace(vis.style, gloss=Gloss(args.gloss) if args.gloss > 0 else None)
    poses = []
    for _ in range(args.frames):
        g = track.gates[int(rng.integers(len(track.gates)))]
        pos = np.asarray(g.pos) - rng.uniform(1.5, 10.0) * g.normal + rng.normal(0.0, 0.5, 3)
        rpy = np.array(
            [rng.uniform(-0.6, 0.6), rng.uniform(-0.4, 0.4), g.yaw + rng.uniform(-0.4, 0.4)]
        )
        poses.append((pos, rpy_to_quat(rpy[None])[0]))
    egl = args.renderer == "egl"
    with Scene(track, vis.camera, style, vis.distractors, egl=egl) as scene:
        scene.render(*poses[0], light)  # warm-up
        t0 = time.perf_counter()
        for pos, quat in poses:
            scene.render(pos, quat, light)
        render_fps = len(poses) / (time.perf_counter() - t0)
        t0 = time.perf_counter()
        n_labels = 0
        for pos, quat in poses:
            frame = scene.render(pos, quat, light)
            n_labels += len(frame_labels(scene, frame, pos, quat))
            apply_sensor_noise(frame.rgb, vis.sensor, rng)
        full_fps = len(poses) / (time.perf_counter() - t0)
    print(json.dumps({
        "renderer": scene.renderer, "shadows": args.shadows, "gloss": args.gloss,
        "frames": len(poses), "width": scene.camera.width, "height": scene.camera.height,
        "render_fps": round(render_fps, 1), "labelled_fps": round(full_fps, 1),
        "labels_per_frame": round(n_labels / len(poses), 2),
    }))  # fmt: skip


if __name__ == "__main__":
    main()
