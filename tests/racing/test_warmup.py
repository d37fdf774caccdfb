"""The detector warm-up that keeps numba compilation out of a race's clock."""

from __future__ import annotations

from icarus_vision.gate_detect.registry import make_detector
from icarus_vision.racing.warmup import warm_up
from icarus_vision.render.camera import Camera
from icarus_vision.render.scene import Scene
from icarus_vision.sim.builtin import builtin_track
from icarus_vision.sim.quad import QuadParams


def test_warm_up_detects_the_first_gate_from_the_start():
    track = builtin_track("single-gate")
    scene = Scene(track, Camera.from_params(QuadParams().camera))
    try:
        assert warm_up(make_detector("cnn"), scene, track) == 1
    finally:
        scene.close()
