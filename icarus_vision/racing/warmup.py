"""Pay the detector's one-time costs before a race: numba compilation and the first inference.

The CNN's decoding and geometry are compiled with numba on first use (about 30 s once per
checkout, then loaded from ``__pycache__``). ``warm_up`` runs a detector on the view from a track's
start, so that cost is paid before a race's clock starts; ``python -m icarus_vision.racing.warmup``
does it for the shipped detector (the Makefile's install step runs it).
"""

from __future__ import annotations

import math

import numpy as np

from icarus_vision.gate_detect.base import Detector
from icarus_vision.render.camera import Camera
from icarus_vision.sim.dynamics import rpy_to_quat
from icarus_vision.sim.track import Track


def warm_up(detector: Detector, scene, track: Track) -> int:
    """Detect once in the image seen from ``track``'s start, looking at its first gate.

    Returns:
        The number of gates detected (the first gate is normally in view).
    """
    start = np.asarray(track.start_pos, float)
    to_gate = np.asarray(track.gates[0].pos) - start
    yaw = math.atan2(to_gate[1], to_gate[0])
    quat = rpy_to_quat(np.array([[0.0, 0.0, yaw]]))[0]
    return len(detector.detect(scene.render(start, quat).rgb))


def main() -> None:
    from icarus_vision.gate_detect.registry import make_detector
    from icarus_vision.render.scene import Scene
    from icarus_vision.sim.builtin import builtin_track
    from icarus_vision.sim.quad import QuadParams

    track = builtin_track("single-gate")
    scene = Scene(track, Camera.from_params(QuadParams().camera))
    try:
        found = warm_up(make_detector("cnn"), scene, track)
    finally:
        scene.close()
    print(f"detector compiled and warmed up ({found} gate(s) in the test view)")


if __name__ == "__main__":
    main()
