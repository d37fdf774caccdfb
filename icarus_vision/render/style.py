"""Descriptions of how a scene looks: materials of gates, ground and sky, distractors, light.

Plain frozen dataclasses, drawn by :mod:`icarus_vision.render.randomize` and consumed by
:class:`icarus_vision.render.scene.Scene`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from icarus_vision.render.textures import Material

DISTRACTOR_SHAPES = ("box", "cylinder", "sphere", "frame", "arch", "pole", "person", "tree", "net",
                     "banner", "screen")  # fmt: skip


@dataclass(frozen=True)
class Lighting:
    """Light of one frame: PyBullet's directional light. TinyRenderer and the ground honour all of
    it; the EGL renderer only the direction (fixed strengths, white light, no shadows on objects)."""

    direction: tuple[float, float, float] = (0.4, 0.3, 1.0)
    """World direction *towards* the light."""
    color: tuple[float, float, float] = (1.0, 1.0, 1.0)
    """Light RGB colour in [0, 1]."""
    ambient: float = 0.6
    """Ambient coefficient."""
    diffuse: float = 0.35
    """Diffuse coefficient."""
    specular: float = 0.05
    """Specular coefficient."""
    shadows: bool = False
    """Cast shadows: on objects (TinyRenderer's shadow map; not with EGL) and on the ground."""


@dataclass(frozen=True)
class Distractor:
    """A non-gate object in the world (never labelled)."""

    shape: str
    """One of ``box``, ``cylinder``, ``sphere``, ``frame`` (closed non-square frame), ``arch``
    (frame without its bottom bar), ``pole``, ``person``, ``tree``, ``net`` (a grid of thin bars)
    ``banner`` (a thin board) or ``screen`` (a filled rectangle in a bezel: a monitor, a window,
    a door, a whiteboard; square or not)."""
    pos: tuple[float, float, float]
    """World position of the object's centre, m."""
    size: tuple[float, float, float]
    """Extents, m: box x, y, z; cylinder/pole (radius, radius, height); sphere (radius, -, -);
    frame/arch (opening width, opening height, bar width); person/tree (width, -, height);
    net (width, height, mesh cell); banner (width, height, thickness); screen (panel width, panel
    height, bezel width)."""
    yaw_deg: float = 0.0
    """Heading about world z, degrees."""
    material: Material = field(default_factory=Material)
    """Surface look."""
    material2: Material | None = None
    """A second part's look: a person's head, a tree's crown, a screen's panel."""

    def __post_init__(self) -> None:
        if self.shape not in DISTRACTOR_SHAPES:
            raise ValueError(
                f"distractor shape must be one of {DISTRACTOR_SHAPES}, got {self.shape!r}"
            )


@dataclass(frozen=True)
class Trim:
    """A lining of every gate's opening (an LED strip or padding); its inner edge is the opening."""

    material: Material
    """Its look (an LED's colour)."""
    width: float
    """Width, m."""
    led: bool = False
    """An LED strip: drawn at its colour's full brightness whatever the light, with a glow."""


@dataclass(frozen=True)
class Hall:
    """An indoor hall around the track: four walls, a ceiling, lights, trusses, banners."""

    lo: tuple[float, float]
    """World x, y of the hall's corner with the smallest coordinates, m."""
    hi: tuple[float, float]
    """The opposite corner, m."""
    height: float
    """Ceiling height, m."""
    walls: Material
    """Look of the walls."""
    ceiling: Material
    """Look of the ceiling."""
    lights: tuple[tuple[float, float, float], ...] = ()
    """Ceiling light panels: (x, y, side) each, m (emissive, white)."""
    trusses: bool = False
    """Rows of bars under the ceiling."""
    banners: tuple[tuple[int, float, float, float, float, Material], ...] = ()
    """(wall 0-3, position along it 0-1, height m, width m, height m, look) each."""


@dataclass(frozen=True)
class Gloss:
    """A glossy floor: the ground z = 0 reflects the objects above it like a dim mirror."""

    reflectivity: float
    """Share of a floor pixel's colour taken from the reflection where one is seen, in [0, 1]."""
    blur_px: float = 0.0
    """Gaussian blur sigma of the reflection, pixels (a slightly rough gloss); 0: sharp."""


@dataclass(frozen=True)
class SceneStyle:
    """How the world looks (everything the domain randomisation varies at build time)."""

    gate_materials: tuple[Material, ...] = (Material("solid", (1.0, 0.35, 0.0)),)
    """Gate looks; physical gate i uses ``gate_materials[i % len]``."""
    frame_width: float | None = None
    """Rendered bar width, m; None keeps each gate's own ``frame_width``."""
    ground: Material = field(
        default_factory=lambda: Material("checker", (0.36, 0.5, 0.3), (0.3, 0.44, 0.25), 4.0)
    )
    """Ground plane z = 0 look (``tile_m`` in metres)."""
    background: Material = field(
        default_factory=lambda: Material("solid", (0.62, 0.76, 0.92), (0.8, 0.85, 0.95), 40.0)
    )
    """Sky: painted, in image space, where no object or ground is seen (``tile_m`` in pixels)."""
    frame_depth: float | None = None
    """Rendered bar depth along the passage, m; None: as deep as wide."""
    trim: Trim | None = None
    """A lining of the gates' openings (an LED strip or padding), or none."""
    hall: Hall | None = None
    """An indoor hall around the track, or none (outdoors)."""
    gloss: Gloss | None = None
    """A glossy floor that reflects the objects (a second render), or none (a matte floor)."""


@dataclass(frozen=True)
class Frame:
    """One rendered image.

    Attributes:
        rgb: (H, W, 3) uint8.
        seg: (H, W) int32 PyBullet body id per pixel; ``SKY_ID`` (-1) for sky, ``GROUND_ID`` (-2)
            for ground.
        depth: (H, W) float32 z along the optical axis, m (about ``camera.far`` for sky).
    """

    rgb: np.ndarray
    seg: np.ndarray
    depth: np.ndarray
