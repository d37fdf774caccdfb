"""Triangle meshes (vertices, indices, normals, UVs) for the PyBullet scene.

Every mesh is returned as a :class:`Mesh` in its body's local frame. UVs are in metres / ``tile_m``
so a texture tile covers ``tile_m`` metres of surface whatever the size of the part.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Mesh:
    """An indexed triangle mesh.

    Attributes:
        vertices: (V, 3) float64 local coordinates, m.
        normals: (V, 3) float64 unit normals.
        uvs: (V, 2) float64 texture coordinates.
        indices: (T * 3,) int32 counter-clockwise triangles seen from outside.
    """

    vertices: np.ndarray
    normals: np.ndarray
    uvs: np.ndarray
    indices: np.ndarray

    @staticmethod
    def concat(parts: list[Mesh]) -> Mesh:
        offs = np.cumsum([0] + [len(m.vertices) for m in parts[:-1]])
        return Mesh(
            np.concatenate([m.vertices for m in parts]),
            np.concatenate([m.normals for m in parts]),
            np.concatenate([m.uvs for m in parts]),
            np.concatenate([m.indices + o for m, o in zip(parts, offs, strict=True)]).astype(
                np.int32
            ),
        )


def box_mesh(center, half_extents, tile_m: float = 1.0, long_axis: int | None = None) -> Mesh:
    """An axis-aligned box of 6 faces (4 vertices each, so every face has its own normal).

    Args:
        center: (3,) box centre, local frame.
        half_extents: (3,) half sizes along x, y, z.
        tile_m: metres per texture tile.
        long_axis: axis along which U runs on the side faces (stripes then go across a bar);
            default: the longest axis.
    """
    c, h = np.asarray(center, dtype=float), np.asarray(half_extents, dtype=float)
    if long_axis is None:
        long_axis = int(np.argmax(h))
    verts, norms, uvs, idx = [], [], [], []
    for a in range(3):
        b, d = (a + 1) % 3, (a + 2) % 3
        for sign in (1.0, -1.0):
            n = np.zeros(3)
            n[a] = sign
            corners = [(-1, -1), (1, -1), (1, 1), (-1, 1)]
            if sign < 0:
                corners = corners[::-1]
            base = len(verts)
            for sb, sd in corners:
                p = c.copy()
                p[a] += sign * h[a]
                p[b] += sb * h[b]
                p[d] += sd * h[d]
                verts.append(p)
                norms.append(n)
                u_ax, v_ax = (b, d) if long_axis != d else (d, b)
                uvs.append([p[u_ax] / tile_m, p[v_ax] / tile_m])
            idx += [base, base + 1, base + 2, base, base + 2, base + 3]
    return Mesh(np.array(verts), np.array(norms), np.array(uvs), np.array(idx, dtype=np.int32))


BOX_VERTICES = 24
"""Vertices of one :func:`box_mesh` (4 per face, the 8 corners first)."""


def box_corners(mesh: Mesh) -> np.ndarray:
    """Corners of each box of a mesh made of :func:`box_mesh` boxes (a box, a frame, a gate).

    Returns:
        (B, 8, 3) corners of the B boxes, the mesh's local frame.
    """
    v = mesh.vertices
    if len(v) % BOX_VERTICES:
        raise ValueError(f"not a mesh of boxes: {len(v)} vertices is no multiple of {BOX_VERTICES}")
    return v.reshape(-1, BOX_VERTICES, 3)[:, :8]


def frame_mesh(
    inner_w: float, inner_h: float, bar: float, depth: float, tile_m: float, sides: int = 4
) -> Mesh:
    """A rectangular frame of box bars around an opening in the local y-z plane (x = depth axis).

    Args:
        inner_w: opening width along y, m.
        inner_h: opening height along z, m.
        bar: bar width, m.
        depth: bar depth along x, m.
        tile_m: metres per texture tile.
        sides: 4 for a closed frame; 3 leaves the bottom bar out (an arch), 2 keeps top and left.
    """
    hw, hh, hd = inner_w / 2.0, inner_h / 2.0, depth / 2.0
    top = box_mesh((0, 0, hh + bar / 2), (hd, hw + bar, bar / 2), tile_m, long_axis=1)
    left = box_mesh((0, hw + bar / 2, 0), (hd, bar / 2, hh), tile_m, long_axis=2)
    right = box_mesh((0, -hw - bar / 2, 0), (hd, bar / 2, hh), tile_m, long_axis=2)
    bottom = box_mesh((0, 0, -hh - bar / 2), (hd, hw + bar, bar / 2), tile_m, long_axis=1)
    parts = [top, left, right, bottom][: {4: 4, 3: 3, 2: 2}[sides]]
    return Mesh.concat(parts)


def gate_mesh(size: float, frame_width: float, tile_m: float) -> Mesh:
    """A race gate: square opening ``size``, bars ``frame_width`` wide and as deep as wide."""
    return frame_mesh(size, size, frame_width, frame_width, tile_m)


def ground_mesh(center_xy, half_size: float, cell: float, tile_m: float) -> Mesh:
    """The ground z = 0 as a grid of up-facing quads (small cells keep near-plane artefacts away).

    Args:
        center_xy: (2,) world x, y of the grid's centre.
        half_size: half the side of the square, m.
        cell: side of one grid cell, m.
        tile_m: metres per texture tile.
    """
    n = max(1, int(np.ceil(2 * half_size / cell)))
    xs = center_xy[0] - half_size + cell * np.arange(n + 1)
    ys = center_xy[1] - half_size + cell * np.arange(n + 1)
    gx, gy = np.meshgrid(xs, ys, indexing="ij")
    verts = np.stack([gx, gy, np.zeros_like(gx)], axis=-1).reshape(-1, 3)
    i, j = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    v00 = (i * (n + 1) + j).ravel()
    v10, v01, v11 = v00 + (n + 1), v00 + 1, v00 + n + 2
    idx = np.stack([v00, v10, v11, v00, v11, v01], axis=-1).ravel().astype(np.int32)
    norms = np.tile([0.0, 0.0, 1.0], (len(verts), 1))
    return Mesh(verts, norms, verts[:, :2] / tile_m, idx)
