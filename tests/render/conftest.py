from __future__ import annotations

import numpy as np
import pytest

from icarus_vision.render.camera import Camera
from icarus_vision.render.scene import Scene, SceneStyle
from icarus_vision.render.textures import Material
from icarus_vision.sim.track import Gate, Track

GATE_RGB = (1.0, 0.0, 0.0)
LEVEL = np.array([0.0, 0.0, 0.0, 1.0])
EYE = np.array([0.0, 0.0, 2.0])


@pytest.fixture
def one_gate_scene():
    """A red gate 4 m straight ahead of a level camera without uptilt, at the camera's height."""
    track = Track("one", (Gate((4.0, 0.0, 2.0)),), start_pos=(0.0, 0.0, 0.2))
    style = SceneStyle(gate_materials=(Material("solid", GATE_RGB),))
    scene = Scene(track, Camera(uptilt_deg=0.0), style)
    yield scene
    scene.close()
