"""A headless PyBullet world built from a Track, and FPV rendering of it.

Every call passes this scene's own ``physicsClientId``; the default client is never used, so many
scenes (one per dataset worker) can live in one process. Rendering uses TinyRenderer (CPU, no
display) unless ``egl=True`` asks for PyBullet's EGL plugin (OpenGL; :mod:`.egl`), which builds the
meshes from OBJ files instead of in-memory vertices; where the plugin cannot load, the scene warns
and uses TinyRenderer. With ``Lighting.shadows`` the objects also shadow the ground
(:mod:`.shadows`), which neither renderer does since the ground is ray-cast (:mod:`.backdrop`);
with ``SceneStyle.gloss`` the ground reflects them (a second render of the world mirrored through
it, only where the ground is seen).
"""

from __future__ import annotations

import contextlib
import hashlib
import math
import shutil
import tempfile
import warnings
from pathlib import Path

import cv2
import numpy as np

from icarus_vision.render.backdrop import (
    GROUND_ID,
    blend_reflection,
    paint_backdrop,
    ray_norms,
    shade_factor,
)
from icarus_vision.render.camera import (
    HARDWARE_OPENGL_SAMPLE_OFFSET,
    TINY_RENDERER_SAMPLE_OFFSET,
    Camera,
    gl_view_matrix,
)
from icarus_vision.render.egl import load_egl_plugin, quiet_c_stdout, write_obj
from icarus_vision.render.meshes import Mesh, box_corners, box_mesh, frame_mesh
from icarus_vision.render.shadows import cylinder_points, ground_shadow_mask, place, sphere_points
from icarus_vision.render.style import (
    DISTRACTOR_SHAPES,
    Distractor,
    Frame,
    Gloss,
    Lighting,
    SceneStyle,
)
from icarus_vision.render.textures import Material, texture_image
from icarus_vision.sim.bullet import p
from icarus_vision.sim.track import Track

__all__ = ["DISTRACTOR_SHAPES", "Distractor", "Frame", "Gloss", "Lighting", "Scene", "SceneStyle"]

RENDERERS = ("tiny", "egl")
"""Renderers of a scene (:attr:`Scene.renderer`): PyBullet's TinyRenderer, or its EGL plugin."""

_MIRROR_Z = np.diag([1.0, 1.0, -1.0, 1.0])
"""World points mirrored through the floor z = 0 (homogeneous)."""


def _yaw_quat(yaw: float) -> list[float]:
    return [0.0, 0.0, math.sin(yaw / 2.0), math.cos(yaw / 2.0)]


class Scene:
    """A PyBullet DIRECT world holding a track's physical gates, the ground and distractors.

    Attributes:
        track: the track it was built from.
        camera: the camera used by :meth:`render`.
        client: PyBullet physics client id of this scene.
        gate_bodies: body id of each physical gate, in ``track.physical_gates()`` order.
        distractor_bodies: body id of each distractor.
        renderer: ``"tiny"`` (TinyRenderer) or ``"egl"`` (the EGL plugin's OpenGL renderer).
    """

    def __init__(
        self,
        track: Track,
        camera: Camera | None = None,
        style: SceneStyle | None = None,
        distractors: tuple[Distractor, ...] = (),
        *,
        egl: bool = False,
    ) -> None:
        self.track = track
        self.camera = camera or Camera()
        self.style = style or SceneStyle()
        self.client = p.connect(p.DIRECT)
        self._tmp = Path(tempfile.mkdtemp(prefix="icarus-render-"))
        self._textures: dict[str, int] = {}
        self._obj_files: dict[str, str] = {}
        self._casters: list[np.ndarray] = []  # world points of each convex shadow-casting part
        self._caster_arrays: tuple[np.ndarray, np.ndarray] | None = None
        self.renderer = "tiny"
        self._emissive: dict[int, tuple[float, float, float]] = {}  # body -> its colour, lit
        self._alias: dict[int, int] = {}  # body -> the body it counts as (a trim: its gate)
        try:
            if egl:
                self._load_egl()
            self.gates = track.physical_gates()
            self.gate_bodies = tuple(self._add_gate(i, g) for i, g in enumerate(self.gates))
            self.distractor_bodies = tuple(self._add_distractor(d) for d in distractors)
            if self.style.hall is not None:
                self._add_hall(self.style.hall)
        except BaseException:
            self.close()
            raise
        self._sky = self._sky_image()
        self._ground_tex = texture_image(self.style.ground)
        self._rays: dict[Camera, np.ndarray] = {}
        self._lens_maps: dict[Camera, tuple] = {}  # cv2.remap maps of distorted cameras
        self._luts = self._lookup_tables()

    # -- building ---------------------------------------------------------------------------------
    def _load_egl(self) -> None:
        try:
            load_egl_plugin(self.client)
        except RuntimeError as e:
            warnings.warn(f"EGL rendering unavailable ({e}); using TinyRenderer", stacklevel=3)
        else:
            self.renderer = "egl"

    def _texture(self, material: Material) -> int:
        key = hashlib.sha1(repr(material).encode()).hexdigest()[:16]
        if key not in self._textures:
            path = self._tmp / f"{key}.png"
            cv2.imwrite(str(path), cv2.cvtColor(texture_image(material), cv2.COLOR_RGB2BGR))
            self._textures[key] = p.loadTexture(str(path), physicsClientId=self.client)
        return self._textures[key]

    def _obj_file(self, mesh: Mesh) -> str:
        """An OBJ file of ``mesh`` in this scene's folder (for the EGL plugin), written once."""
        arrays = (mesh.vertices, mesh.normals, mesh.uvs, mesh.indices)
        key = hashlib.sha1(b"".join(a.tobytes() for a in arrays)).hexdigest()[:16]
        if key not in self._obj_files:
            path = self._tmp / f"mesh-{key}.obj"
            write_obj(mesh, path)
            self._obj_files[key] = str(path)
        return self._obj_files[key]

    def _add_casters(self, parts: np.ndarray, pos, yaw: float) -> None:
        """Shadow-casting convex parts: (P, K, 3) points of P parts, body frame at pos, yaw."""
        self._casters += list(place(parts, pos, yaw))
        self._caster_arrays = None

    def _add_mesh(
        self, mesh: Mesh, material: Material, pos, yaw: float = 0.0, casts: bool = True
    ) -> int:
        """A static body of a mesh made of boxes (:func:`box_corners`), which cast shadows
        unless ``casts`` is False (a hall's walls and ceiling)."""
        if self.renderer == "egl":  # the plugin crashes on in-memory meshes
            geometry = {"fileName": self._obj_file(mesh), "meshScale": [1.0, 1.0, 1.0]}
        else:
            geometry = {
                "vertices": mesh.vertices.tolist(),
                "indices": mesh.indices.tolist(),
                "normals": mesh.normals.tolist(),
                "uvs": mesh.uvs.tolist(),
            }
        vis = p.createVisualShape(
            p.GEOM_MESH, rgbaColor=material.rgba, physicsClientId=self.client, **geometry
        )
        if casts:
            self._add_casters(box_corners(mesh), pos, yaw)
        body = p.createMultiBody(
            baseMass=0.0,
            baseVisualShapeIndex=vis,
            basePosition=list(map(float, pos)),
            baseOrientation=_yaw_quat(yaw),
            physicsClientId=self.client,
        )
        self._set_material(body, material)
        return body

    def _set_material(self, body: int, material: Material) -> None:
        kw = {"textureUniqueId": self._texture(material)} if material.textured else {}
        p.changeVisualShape(body, -1, rgbaColor=material.rgba, physicsClientId=self.client, **kw)

    def _add_gate(self, i: int, gate) -> int:
        mats = self.style.gate_materials
        mat = mats[i % len(mats)]
        fw = self.style.frame_width or gate.frame_width
        depth = self.style.frame_depth or fw
        body = self._add_mesh(frame_mesh(gate.size, gate.size, fw, depth, mat.tile_m), mat,
                              gate.pos, gate.yaw)  # fmt: skip
        trim = self.style.trim
        if trim is not None:  # lines the opening, a little proud of the bars on both faces
            mesh = frame_mesh(gate.size, gate.size, min(trim.width, fw), depth + 0.02, 1.0)
            lining = self._add_mesh(mesh, trim.material, gate.pos, gate.yaw, casts=False)
            self._alias[lining] = body
            if trim.led:
                self._emissive[lining] = trim.material.color
        return body

    def _add_distractor(self, d: Distractor) -> int:
        sx, sy, sz = d.size
        tile = d.material.tile_m
        if d.shape in ("frame", "arch"):
            mesh = frame_mesh(sx, sy, sz, sz, tile, sides=4 if d.shape == "frame" else 3)
            return self._add_mesh(mesh, d.material, d.pos, math.radians(d.yaw_deg))
        if d.shape == "box":
            mesh = box_mesh((0, 0, 0), (sx / 2, sy / 2, sz / 2), tile)
            return self._add_mesh(mesh, d.material, d.pos, math.radians(d.yaw_deg))
        if d.shape in ("person", "tree", "net", "banner", "screen"):
            return self._add_figure(d)
        if d.shape == "sphere":
            vis = p.createVisualShape(p.GEOM_SPHERE, radius=sx, physicsClientId=self.client)
            part = sphere_points(sx)
        else:  # cylinder, pole
            vis = p.createVisualShape(
                p.GEOM_CYLINDER, radius=sx, length=sz, physicsClientId=self.client
            )
            part = cylinder_points(sx, sz)
        self._add_casters(part[None], d.pos, math.radians(d.yaw_deg))
        body = p.createMultiBody(
            0.0, -1, vis, list(map(float, d.pos)), _yaw_quat(math.radians(d.yaw_deg)),
            physicsClientId=self.client,
        )  # fmt: skip
        self._set_material(body, d.material)
        return body

    def _add_figure(self, d: Distractor) -> int:
        """A person, tree, net, banner or screen (:class:`Distractor`); the first part's body id."""
        sx, sy, sz = d.size
        x, y = d.pos[:2]
        yaw = math.radians(d.yaw_deg)
        if d.shape == "screen":  # a bezel around a panel, facing x; the panel sits in its middle
            bezel = self._add_mesh(frame_mesh(sx, sy, sz, 0.06, d.material.tile_m), d.material,
                                   d.pos, yaw)  # fmt: skip
            panel = box_mesh((0, 0, 0), (0.02, sx / 2, sy / 2), (d.material2 or d.material).tile_m)
            self._add_mesh(panel, d.material2 or d.material, d.pos, yaw)
            return bezel
        if d.shape == "banner":
            return self._add_mesh(box_mesh((0, 0, 0), (sz / 2, sx / 2, sy / 2), d.material.tile_m),
                                  d.material, d.pos, yaw)  # fmt: skip
        if d.shape == "net":  # a fence of thin bars, sx wide, sy high, cells of sz
            bar = 0.015
            parts = [box_mesh((0, yy, 0), (bar, bar, sy / 2), 1.0, long_axis=2)
                     for yy in np.arange(-sx / 2, sx / 2 + 1e-9, sz)]  # fmt: skip
            parts += [box_mesh((0, 0, zz), (bar, sx / 2, bar), 1.0, long_axis=1)
                      for zz in np.arange(-sy / 2, sy / 2 + 1e-9, sz)]  # fmt: skip
            return self._add_mesh(Mesh.concat(parts), d.material, d.pos, yaw)
        # a person: a body, a head above it; a tree: a trunk, a crown on top
        if d.shape == "person":
            stem_r, stem_h, r = sx / 2, 0.88 * sz, 0.07 * sz
            top = stem_h + r
        else:
            stem_r, stem_h, r = 0.06 * sz, 0.6 * sz, sx / 2
            top = sz - r
        stem = self._add_distractor(Distractor("cylinder", (x, y, stem_h / 2),
                                               (stem_r, stem_r, stem_h), d.yaw_deg, d.material))  # fmt: skip
        self._add_distractor(Distractor("sphere", (x, y, top), (r, r, r), d.yaw_deg,
                                        d.material2 or d.material))  # fmt: skip
        return stem

    def _add_hall(self, hall) -> None:
        """Walls, ceiling, ceiling lights, trusses and banners of an indoor hall (:class:`Hall`);
        none of them casts a shadow (the light stands for the hall's many lamps)."""
        (x0, y0), (x1, y1), h = hall.lo, hall.hi, hall.height
        cx, cy, hx, hy, t = (x0 + x1) / 2, (y0 + y1) / 2, (x1 - x0) / 2, (y1 - y0) / 2, 0.1
        tile = hall.walls.tile_m
        for centre, half in (((cx, y0 - t, h / 2), (hx + 2 * t, t, h / 2)),
                             ((cx, y1 + t, h / 2), (hx + 2 * t, t, h / 2)),
                             ((x0 - t, cy, h / 2), (t, hy, h / 2)),
                             ((x1 + t, cy, h / 2), (t, hy, h / 2))):  # fmt: skip
            self._add_mesh(box_mesh((0, 0, 0), half, tile), hall.walls, centre, casts=False)
        self._add_mesh(box_mesh((0, 0, 0), (hx + 2 * t, hy + 2 * t, t), hall.ceiling.tile_m),
                       hall.ceiling, (cx, cy, h + t), casts=False)  # fmt: skip
        lamp = Material("solid", (1.0, 0.98, 0.92))
        for lx, ly, side in hall.lights:
            body = self._add_mesh(box_mesh((0, 0, 0), (side / 2, side / 2, 0.03), 1.0), lamp,
                                  (lx, ly, h - 0.05), casts=False)  # fmt: skip
            self._emissive[body] = lamp.color
        if hall.trusses:
            grey = Material("solid", (0.55, 0.55, 0.58))
            for ty in np.arange(y0 + 3.0, y1 - 1.0, 6.0):
                for dz in (0.6, 1.4):
                    self._add_mesh(box_mesh((0, 0, 0), (hx, 0.04, 0.04), 1.0, long_axis=0), grey,
                                   (cx, float(ty), h - dz), casts=False)  # fmt: skip
        for wall, along, z, w, bh, look in hall.banners:
            if wall < 2:
                pos = (
                    x0 + along * (x1 - x0),
                    (y0 if wall == 0 else y1) + (0.05 if wall == 0 else -0.05),
                    z,
                )
                half = (w / 2, 0.02, bh / 2)
            else:
                pos = (
                    (x0 if wall == 2 else x1) + (0.05 if wall == 2 else -0.05),
                    y0 + along * (y1 - y0),
                    z,
                )
                half = (0.02, w / 2, bh / 2)
            self._add_mesh(box_mesh((0, 0, 0), half, look.tile_m), look, pos, casts=False)

    def _lookup_tables(self) -> tuple[np.ndarray | None, np.ndarray | None]:
        """By segmentation id + 2 (ground is -2): each emissive body's lit colour (0 elsewhere),
        and the id each body counts as (a trim: its gate); None where the scene has none. The
        bodies are all built by now, so both are made once."""
        n = p.getNumBodies(physicsClientId=self.client) + 2
        light = alias = None
        if self._emissive:
            light = np.zeros((n, 3), np.float32)
            ids = np.array(list(self._emissive), np.int64)
            light[ids + 2] = 255.0 * np.asarray(list(self._emissive.values()), np.float32)
        if self._alias:
            alias = np.arange(-2, n - 2, dtype=np.int32)
            alias[np.array(list(self._alias), np.int64) + 2] = list(self._alias.values())
        return light, alias

    def _lit(self, rgb: np.ndarray, seg: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Emissive bodies (LED trims, ceiling lights) at their colour with a glow; trims then
        counted as their gates in ``seg``."""
        light_lut, alias_lut = self._luts
        if light_lut is not None:
            light = light_lut[seg + 2]
            on = light.any(axis=2)
            if on.any():
                glow = cv2.GaussianBlur(light, (0, 0), 0.012 * max(rgb.shape[:2]))
                out = rgb.astype(np.float32) + 1.5 * glow
                out[on] = np.maximum(light[on], 0.85 * 255.0)
                rgb = np.clip(out, 0, 255).astype(np.uint8)
        if alias_lut is not None:
            seg = alias_lut[seg + 2]
        return rgb, seg

    def _sky_image(self) -> np.ndarray:
        bg = self.style.background
        h, w = self.camera.height, self.camera.width
        if not bg.textured:
            return np.broadcast_to(np.round(np.multiply(bg.color, 255)).astype(np.uint8), (h, w, 3))
        tile_px = max(2, int(round(bg.tile_m)))
        tile = cv2.resize(texture_image(bg), (tile_px, tile_px), interpolation=cv2.INTER_LINEAR)
        reps = (h // tile_px + 1, w // tile_px + 1, 1)
        return np.ascontiguousarray(np.tile(tile, reps)[:h, :w])

    # -- rendering --------------------------------------------------------------------------------
    def render(
        self,
        pos: np.ndarray,
        quat: np.ndarray,
        lighting: Lighting | None = None,
        camera: Camera | None = None,
    ) -> Frame:
        """Render the view of a drone at body pose (pos (3,), quat (4,) x, y, z, w).

        Args:
            pos: (3,) body position, world frame, m.
            quat: (4,) body attitude, body -> world.
            lighting: light of this frame (default :class:`Lighting`).
            camera: overrides the scene's camera for this frame (e.g. jittered FOV or roll).

        Returns:
            the RGB image, the segmentation mask (body ids) and metric depth.
        """
        cam = camera or self.camera
        light = lighting or Lighting()
        if cam.distorted:  # the pinhole view of every ray the lens sees, then through the lens
            return self._through_lens(cam, self.render(pos, quat, light, cam.pinhole_cover()[0]))
        w, h = cam.width, cam.height
        r_wc, t_wc = cam.pose(pos, quat)
        view = gl_view_matrix(r_wc, t_wc)
        rgb, seg, depth = self._raster(cam, view, light)
        z = cam.depth_to_z(depth).astype(np.float32)
        if cam not in self._rays:
            self._rays[cam] = ray_norms(cam)
        sky = self._sky
        if sky.shape[:2] != (h, w):
            sky = cv2.resize(np.ascontiguousarray(sky), (w, h), interpolation=cv2.INTER_NEAREST)
        gain = shade_factor(light.direction, light.color, light.ambient, light.diffuse)
        shadow = shadow_gain = None
        if light.shadows:
            shadow = ground_shadow_mask(*self._shadow_casters(), light.direction, cam, r_wc, t_wc)
            shadow_gain = shade_factor(light.direction, light.color, light.ambient, 0.0)
        paint_backdrop(
            rgb, seg, z, cam, self._rays[cam], r_wc, t_wc,
            self._ground_tex, self.style.ground.tile_m, gain, sky, shadow, shadow_gain,
        )  # fmt: skip
        if self.style.gloss is not None:
            self._reflect(rgb, seg, cam, view, light)
        if self._emissive or self._alias:
            rgb, seg = self._lit(rgb, seg)
        return Frame(rgb, seg, z)

    def _raster(
        self,
        cam: Camera,
        view: np.ndarray,
        light: Lighting,
        shadows: bool | None = None,
        rows: tuple[int, int] | None = None,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The objects seen through a (4, 4) world -> eye view matrix, in image rows r0:r1
        (``rows``; default all): RGB (H, W, 3) uint8, body ids (H, W) int32 (-1 where empty) and
        the depth buffer (H, W) float32 in [0, 1]."""
        r0, r1 = rows or (0, cam.height)
        w, h = cam.width, r1 - r0
        egl = self.renderer == "egl"
        offset = HARDWARE_OPENGL_SAMPLE_OFFSET if egl else TINY_RENDERER_SAMPLE_OFFSET
        with self._quiet():
            _, _, rgba, depth, seg = p.getCameraImage(
                w,
                h,
                viewMatrix=view.flatten(order="F").tolist(),
                projectionMatrix=cam.projection_matrix(offset, rows),
                lightDirection=list(map(float, light.direction)),
                lightColor=list(map(float, light.color)),
                lightDistance=100.0,
                shadow=int(light.shadows if shadows is None else shadows),
                lightAmbientCoeff=float(light.ambient),
                lightDiffuseCoeff=float(light.diffuse),
                lightSpecularCoeff=float(light.specular),
                renderer=p.ER_BULLET_HARDWARE_OPENGL if egl else p.ER_TINY_RENDERER,
                physicsClientId=self.client,
            )
        rgb = cv2.cvtColor(np.asarray(rgba, dtype=np.uint8).reshape(h, w, 4), cv2.COLOR_RGBA2RGB)
        seg = np.array(seg, dtype=np.int32).reshape(h, w)
        return rgb, seg, np.asarray(depth, dtype=np.float32).reshape(h, w)

    def _reflect(
        self, rgb: np.ndarray, seg: np.ndarray, cam: Camera, view: np.ndarray, light: Lighting
    ) -> None:
        """Blend the reflection of the objects into the floor pixels of a glossy floor, in place.

        The world mirrored through z = 0 is rendered from the same camera (view @ diag(1, 1, -1, 1),
        so its pixels line up with ``rgb``; TinyRenderer draws both windings alike), without
        shadows, in the band of rows that holds floor, and blended into the floor where it shows
        an object (:func:`blend_reflection`).
        """
        rows = np.flatnonzero((seg == GROUND_ID).any(axis=1))
        if len(rows) == 0:  # the second render only where it is seen
            return
        gloss = self.style.gloss
        pad = int(np.ceil(3.0 * gloss.blur_px))
        r0, r1 = max(0, int(rows[0]) - pad), min(cam.height, int(rows[-1]) + 1 + pad)
        mirror, mirror_seg, _ = self._raster(cam, view @ _MIRROR_Z, light, False, (r0, r1))
        if self._emissive or self._alias:  # ceiling lights and LED trims glow in the floor too
            mirror, mirror_seg = self._lit(mirror, mirror_seg)
        blend_reflection(rgb[r0:r1], seg[r0:r1] == GROUND_ID, mirror, mirror_seg >= 0,
                         gloss.reflectivity, gloss.blur_px)  # fmt: skip

    def _through_lens(self, cam: Camera, pinhole: Frame) -> Frame:
        """The frame ``cam`` takes, from the render of its pinhole cover: colours interpolated,
        segmentation and depth from the nearest pinhole pixel."""
        if cam not in self._lens_maps:
            mx, my = cam.lens_maps()
            near = (np.clip(np.rint(my), -1, pinhole.rgb.shape[0]).astype(np.intp),
                    np.clip(np.rint(mx), -1, pinhole.rgb.shape[1]).astype(np.intp))  # fmt: skip
            self._lens_maps[cam] = (mx, my, near)
        mx, my, (rows, cols) = self._lens_maps[cam]
        rgb = cv2.remap(pinhole.rgb, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
        h, w = pinhole.seg.shape
        outside = (rows < 0) | (rows >= h) | (cols < 0) | (cols >= w)
        r, c = np.clip(rows, 0, h - 1), np.clip(cols, 0, w - 1)
        seg = np.where(outside, -1, pinhole.seg[r, c]).astype(np.int32)
        depth = np.where(outside, np.float32(cam.far), pinhole.depth[r, c]).astype(np.float32)
        return Frame(rgb, seg, depth)

    def _quiet(self) -> contextlib.AbstractContextManager:
        """Silences the EGL plugin's banners (TinyRenderer prints none)."""
        egl = getattr(self, "renderer", "tiny") == "egl"  # absent when __init__ failed early
        return quiet_c_stdout() if egl else contextlib.nullcontext()

    def _shadow_casters(self) -> tuple[np.ndarray, np.ndarray]:
        """(M, 3) world points of every shadow-casting part, and (P,) the index of each one's first."""
        if self._caster_arrays is None:
            sizes = [len(c) for c in self._casters]
            points = np.concatenate(self._casters) if sizes else np.zeros((0, 3))
            self._caster_arrays = (points, np.cumsum([0] + sizes[:-1]).astype(np.intp))
        return self._caster_arrays

    def gate_index_of_body(self, body: int) -> int | None:
        """Physical gate index of a body id, None for non-gate bodies."""
        try:
            return self.gate_bodies.index(body)
        except ValueError:
            return None

    def add_box(self, center, half_extents, color=(0.5, 0.5, 0.5)) -> int:
        """Add a plain box (an occluder in tests, an obstacle in a scene); returns its body id."""
        mat = Material("solid", tuple(map(float, color)))
        return self._add_mesh(box_mesh((0.0, 0.0, 0.0), half_extents, 1.0), mat, center)

    # -- lifetime ---------------------------------------------------------------------------------
    def close(self) -> None:
        """Disconnect the PyBullet client and delete the texture and mesh files (idempotent)."""
        if getattr(self, "client", -1) >= 0:
            try:
                with self._quiet():
                    p.disconnect(physicsClientId=self.client)
            except p.error:
                pass
            self.client = -1
        shutil.rmtree(getattr(self, "_tmp", ""), ignore_errors=True)

    def __enter__(self) -> Scene:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __del__(self) -> None:  # pragma: no cover - safety net only
        try:
            self.close()
        except Exception:  # noqa: BLE001
            pass
