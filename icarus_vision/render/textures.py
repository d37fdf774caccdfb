"""Procedural materials: a colour pattern (solid, stripes, checker, noise) as an RGB texture image.

A :class:`Material` is a small frozen description; :func:`texture_image` turns it into pixels. The
texture covers one tile of ``tile_m`` metres; meshes set their UVs in metres / ``tile_m`` and the
renderer repeats the tile.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

KINDS = ("solid", "stripes", "checker", "noise")
TEXTURE_PX = 64


@dataclass(frozen=True)
class Material:
    """The look of a surface."""

    kind: str = "solid"
    """Pattern: one of ``solid``, ``stripes``, ``checker``, ``noise``."""
    color: tuple[float, float, float] = (1.0, 0.35, 0.0)
    """Main RGB colour, each in [0, 1]."""
    color2: tuple[float, float, float] = (0.1, 0.1, 0.1)
    """Second RGB colour of the pattern (unused by ``solid``)."""
    tile_m: float = 0.2
    """Side of one texture tile on the surface, m (one stripe pair, one 2x2 checker block)."""
    seed: int = 0
    """Seed of the ``noise`` pattern."""

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise ValueError(f"material kind must be one of {KINDS}, got {self.kind!r}")
        for name in ("color", "color2"):
            c = getattr(self, name)
            if len(c) != 3 or not all(0.0 <= float(x) <= 1.0 for x in c):
                raise ValueError(f"material {name} must be 3 numbers in [0, 1], got {c!r}")
        if not self.tile_m > 0:
            raise ValueError(f"material tile_m must be > 0, got {self.tile_m}")

    @property
    def textured(self) -> bool:
        return self.kind != "solid"

    @property
    def rgba(self) -> list[float]:
        """Colour to give the renderer: the solid colour, or white to show the texture unchanged."""
        return [*map(float, self.color), 1.0] if self.kind == "solid" else [1.0, 1.0, 1.0, 1.0]


def _as_u8(color: tuple[float, float, float]) -> np.ndarray:
    return np.round(np.asarray(color, dtype=float) * 255.0).astype(np.uint8)


def texture_image(material: Material, size: int = TEXTURE_PX) -> np.ndarray:
    """One tile of the material's pattern.

    Args:
        material: the pattern and colours.
        size: side of the square image, pixels.

    Returns:
        (size, size, 3) uint8 RGB image; it tiles seamlessly.
    """
    c1, c2 = _as_u8(material.color), _as_u8(material.color2)
    img = np.empty((size, size, 3), dtype=np.uint8)
    img[:] = c1
    ij = np.arange(size)
    if material.kind == "stripes":
        img[:, ij >= size // 2] = c2  # one stripe pair along u; bars get stripes across them
    elif material.kind == "checker":
        mask = (ij[:, None] >= size // 2) ^ (ij[None, :] >= size // 2)
        img[mask] = c2
    elif material.kind == "noise":
        rng = np.random.default_rng(material.seed)
        coarse = rng.random((8, 8))
        # Wrap-pad then resize so the tile repeats without seams.
        padded = np.pad(coarse, 2, mode="wrap")
        big = cv2.resize(padded, (size * 12 // 8, size * 12 // 8), interpolation=cv2.INTER_CUBIC)
        off = size * 2 // 8
        t = np.clip(big[off : off + size, off : off + size], 0.0, 1.0)[..., None]
        img = np.round(c1 * (1.0 - t) + c2 * t).astype(np.uint8)
    return img
