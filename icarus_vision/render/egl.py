"""PyBullet's EGL renderer plugin: finding and loading it, and meshes as OBJ files for it.

The plugin renders with OpenGL (``ER_BULLET_HARDWARE_OPENGL``) through EGL, without a display: on
the GPU where there is one, else in software (Mesa llvmpipe). Once loaded into a client it renders
every ``getCameraImage`` call of that client, whatever ``renderer`` asks for. PyBullet 3.2's plugin
crashes on meshes given in memory (``createVisualShape(vertices=...)``), so a scene rendered with it
builds its meshes from OBJ files (:func:`write_obj`). The plugin and Mesa print banners on the C
streams when loading, on the first frames and when closing; :func:`quiet_c_stdout` silences them.
"""

from __future__ import annotations

import contextlib
import ctypes
import importlib.util
import os
import sys
from collections.abc import Iterator
from pathlib import Path

from icarus_vision.render.meshes import Mesh
from icarus_vision.sim.bullet import p

_LIBC = ctypes.CDLL(None)


def egl_plugin_path() -> str | None:
    """File of PyBullet's ``eglRenderer`` plugin, None where this PyBullet build has none."""
    spec = importlib.util.find_spec("eglRenderer")
    return None if spec is None else spec.origin


@contextlib.contextmanager
def quiet_c_stdout(stderr: bool = False) -> Iterator[None]:
    """Send what C code prints on stdout (and stderr, when asked) to /dev/null meanwhile.

    Redirects the process's file descriptors, so output of other threads is lost meanwhile too.
    """
    fds = (1, 2) if stderr else (1,)
    sys.stdout.flush()
    sys.stderr.flush()
    saved = {fd: os.dup(fd) for fd in fds}
    try:
        with open(os.devnull, "w") as devnull:
            for fd in fds:
                os.dup2(devnull.fileno(), fd)
            try:
                yield
            finally:
                _LIBC.fflush(None)  # push C-buffered output to /dev/null before restoring
    finally:
        for fd, dup in saved.items():
            os.dup2(dup, fd)
            os.close(dup)


def load_egl_plugin(client: int) -> int:
    """Load the EGL renderer plugin into a PyBullet client.

    Returns:
        the plugin id.

    Raises:
        RuntimeError: the plugin is missing or could not start (no EGL library or device); the
            message says which.
    """
    path = egl_plugin_path()
    if path is None:
        raise RuntimeError("this PyBullet build has no eglRenderer plugin")
    with quiet_c_stdout(stderr=True):
        plugin = p.loadPlugin(path, "_eglRendererPlugin", physicsClientId=client)
    if plugin < 0:
        raise RuntimeError(f"PyBullet could not load its EGL plugin {path} (no EGL library?)")
    return plugin


def write_obj(mesh: Mesh, path: str | os.PathLike) -> None:
    """Write a mesh as a Wavefront OBJ file: positions, normals, UVs and 1-based triangles.

    Args:
        mesh: the mesh, in its body's local frame.
        path: the file to write.
    """
    lines = [f"v {x:.9g} {y:.9g} {z:.9g}\n" for x, y, z in mesh.vertices.tolist()]
    lines += [f"vn {x:.9g} {y:.9g} {z:.9g}\n" for x, y, z in mesh.normals.tolist()]
    lines += [f"vt {u:.9g} {v:.9g}\n" for u, v in mesh.uvs.tolist()]
    tri = mesh.indices.reshape(-1, 3) + 1
    lines += [f"f {a}/{a}/{a} {b}/{b}/{b} {c}/{c}/{c}\n" for a, b, c in tri.tolist()]
    Path(path).write_text("".join(lines))
