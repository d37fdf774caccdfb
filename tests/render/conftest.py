from __future__ import annotations

import warnings

import numpy as np
import pytest

from icarus_vision.render.camera import Camera
from icarus_vision.render.scene import RENDERERS, Scene, SceneStyle
from icarus_vision.render.textures import Material
from icarus_vision.sim.track import Gate, Track

GATE_RGB = (1.0, 0.0, 0.0)
LEVEL = np.array([0.0, 0.0, 0.0, 1.0])
EYE = np.array([0.0, 0.0, 2.0])


def _make_scene(renderer: str, *args, **kwargs) -> Scene:
    """``Scene(*args, **kwargs)`` rendered by ``renderer``; skips the test where EGL cannot load."""
    if renderer == "tiny":
        return Scene(*args, **kwargs)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        scene = Scene(*args, egl=True, **kwargs)
    if scene.renderer != "egl":
        scene.close()
        pytest.skip(f"PyBullet's EGL renderer cannot load here: {caught[-1].message}")
    return scene


@pytest.fixture
def make_scene():
    """``make_scene(renderer, *args, **kwargs)``: a Scene rendered by ``"tiny"`` or ``"egl"``."""
    return _make_scene


@pytest.fixture(params=RENDERERS)
def one_gate_scene(request):
    """A red gate 4 m straight ahead of a level camera without uptilt, at the camera's height;
    once per renderer."""
    track = Track("one", (Gate((4.0, 0.0, 2.0)),), start_pos=(0.0, 0.0, 0.2))
    style = SceneStyle(gate_materials=(Material("solid", GATE_RGB),))
    scene = _make_scene(request.param, track, Camera(uptilt_deg=0.0), style)
    yield scene
    scene.close()
