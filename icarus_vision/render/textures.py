"""Procedural materials: a colour pattern (solid, stripes, checker, noise, text, logo) as an RGB
texture image.

A :class:`Material` is a small frozen description; :func:`texture_image` turns it into pixels. The
texture covers one tile of ``tile_m`` metres; meshes set their UVs in metres / ``tile_m`` and the
renderer repeats the tile.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

KINDS = ("solid", "stripes", "checker", "noise")
"""The patterns of the first recipes (the default ``kinds`` of a recipe surface)."""
PRINTED_KINDS = ("text", "logo")
"""Patterns of printed gate panels and banners: random letters, random logo shapes (generated)."""
ALL_KINDS = KINDS + PRINTED_KINDS
"""Every pattern a material may have."""
TEXTURE_PX = 64


@dataclass(frozen=True)
class Material:
    """The look of a surface."""

    kind: str = "solid"
    """Pattern: one of ``solid``, ``stripes``, ``checker``, ``noise``, ``text`` (random capital
    letters and digits in the second colour), ``logo`` (random discs, bars and triangles)."""
    color: tuple[float, float, float] = (1.0, 0.35, 0.0)
    """Main RGB colour, each in [0, 1]."""
    color2: tuple[float, float, float] = (0.1, 0.1, 0.1)
    """Second RGB colour of the pattern (unused by ``solid``)."""
    tile_m: float = 0.2
    """Side of one texture tile on the surface, m (one stripe pair, one 2x2 checker block)."""
    seed: int = 0
    """Seed of the ``noise``, ``text`` and ``logo`` patterns."""

    def __post_init__(self) -> None:
        if self.kind not in ALL_KINDS:
            raise ValueError(f"material kind must be one of {ALL_KINDS}, got {self.kind!r}")
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
    elif material.kind in PRINTED_KINDS:
        img = _printed(material.kind, img, c2, np.random.default_rng(material.seed))
    return img


GLYPHS = "ABCDEFGHIJKLMNOPQRSTUVWXYZ0123456789"


def _printed(kind: str, img: np.ndarray, ink: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """``img`` with random letters (``text``) or logo shapes (``logo``) in ``ink`` (seamless at
    the tile's edges only where the marks leave them free)."""
    size = img.shape[0]
    colour = tuple(int(c) for c in ink)
    if kind == "text":
        for row in range(int(rng.integers(1, 3))):
            text = "".join(
                GLYPHS[int(i)] for i in rng.integers(len(GLYPHS), size=rng.integers(2, 6))
            )
            scale = float(rng.uniform(0.35, 0.8)) * size / 64
            y = int((row + 0.7) * size / 2)
            cv2.putText(img, text, (int(rng.integers(0, size // 4)), y), cv2.FONT_HERSHEY_SIMPLEX,
                        scale, colour, max(1, int(round(2 * scale))), cv2.LINE_AA)  # fmt: skip
        return img
    for _ in range(int(rng.integers(1, 4))):
        c = tuple(int(x) for x in rng.integers(size // 8, size - size // 8, 2))
        r = int(rng.integers(size // 10, size // 3))
        shape = int(rng.integers(3))
        if shape == 0:
            cv2.circle(img, c, r, colour, -1 if rng.random() < 0.5 else 3, cv2.LINE_AA)
        elif shape == 1:
            cv2.rectangle(img, (c[0] - r, c[1] - r // 3), (c[0] + r, c[1] + r // 3), colour, -1)
        else:
            pts = np.array([[c[0], c[1] - r], [c[0] + r, c[1] + r], [c[0] - r, c[1] + r]])
            cv2.fillPoly(img, [pts.astype(np.int32)], colour, cv2.LINE_AA)
    return img
