"""The ground plane and the sky, painted behind the rasterised objects.

TinyRenderer drops triangles that cross the near plane, so a ground mesh shows holes under the
drone. The ground z = 0 is instead ray-cast per pixel: every pixel where no object was drawn looks
along its camera ray; a ray going down meets the ground (textured, lit with the frame's light,
fading to the texture's mean colour where one pixel covers more than a texture tile), the others
show the sky. This is exact: every object lies above the ground, so whatever the rasteriser drew
is in front of it.
"""

from __future__ import annotations

import cv2
import numpy as np

from icarus_vision.render.camera import Camera

SKY_ID = -1
"""Segmentation value of sky pixels."""
GROUND_ID = -2
"""Segmentation value of ground pixels."""


def ray_norms(camera: Camera) -> np.ndarray:
    """(H, W) float32 length of each pixel's camera ray scaled to unit depth."""
    k = camera.K
    x = ((np.arange(camera.width) - k[0, 2]) / k[0, 0]).astype(np.float32)
    y = ((np.arange(camera.height) - k[1, 2]) / k[1, 1]).astype(np.float32)
    return np.sqrt(x[None, :] ** 2 + y[:, None] ** 2 + 1.0).astype(np.float32)


def shade_factor(direction, color, ambient: float, diffuse: float) -> np.ndarray:
    """(3,) RGB gain of an up-facing surface under a directional light (Lambert + ambient)."""
    d = np.asarray(direction, dtype=float)
    n_dot_l = max(0.0, d[2] / max(np.linalg.norm(d), 1e-9))
    return np.asarray(color, dtype=float) * (ambient + diffuse * n_dot_l)


def paint_backdrop(
    rgb: np.ndarray,
    seg: np.ndarray,
    depth: np.ndarray,
    camera: Camera,
    norms: np.ndarray,
    r_world_cam: np.ndarray,
    t_world_cam: np.ndarray,
    ground_tex: np.ndarray,
    ground_tile_m: float,
    ground_gain: np.ndarray,
    sky: np.ndarray,
    shadow: np.ndarray | None = None,
    shadow_gain: np.ndarray | None = None,
) -> None:
    """Fill the empty pixels (``seg == SKY_ID``) with ground or sky, in place.

    The ground texture is warped into the image by the plane's homography (texture repeated by
    wrapping), and faded to its mean colour where one pixel covers more than a quarter tile.
    Ground pixels in ``shadow`` take ``shadow_gain`` instead of ``ground_gain``.

    Args:
        rgb: (H, W, 3) uint8 rendered image, modified.
        seg: (H, W) int32 body ids, ``SKY_ID`` where empty; ground pixels become ``GROUND_ID``.
        depth: (H, W) float32 metric depth, modified on ground pixels.
        camera: the camera that rendered the frame.
        norms: (H, W) from :func:`ray_norms` for that camera.
        r_world_cam: (3, 3) camera rotation; t_world_cam: (3,) camera centre (world).
        ground_tex: (S, S, 3) uint8 one texture tile of the ground.
        ground_tile_m: metres covered by one tile.
        ground_gain: (3,) lighting gain of the ground.
        sky: (H, W, 3) uint8 sky image.
        shadow: (H, W) uint8, 1 where the ground lies in shadow (:mod:`~icarus_vision.render.shadows`),
            None: nowhere.
        shadow_gain: (3,) lighting gain of the ground in shadow (needed with ``shadow``).
    """
    empty = seg == SKY_ID
    if not empty.any():
        return
    h, w = seg.shape
    k = camera.K
    r = np.asarray(r_world_cam, dtype=float)
    t = np.asarray(t_world_cam, dtype=float)
    ground = np.zeros_like(empty)
    if t[2] > 0.0:
        # World z of the unit-depth ray through (u, v) is affine in u and v: negative => ground.
        a = r[2, 0] / k[0, 0]
        b = r[2, 1] / k[1, 1]
        c = r[2, 2] - a * k[0, 2] - b * k[1, 2]
        a, b = np.float32(a), np.float32(b)  # keep the per-pixel maths in float32
        dz = (a * np.arange(w, dtype=np.float32))[None, :] + (b * np.arange(h, dtype=np.float32))[
            :, None
        ]
        dz += np.float32(c)
        np.logical_and(empty, dz < 0.0, out=ground)
    sky_mask = empty & ~ground
    if sky_mask.any():
        cv2.copyTo(sky, sky_mask.view(np.uint8), rgb)
    rows = np.flatnonzero(ground.any(axis=1))
    if len(rows) == 0:
        return
    r0, r1 = int(rows[0]), int(rows[-1]) + 1
    g, dzs = ground[r0:r1], dz[r0:r1]
    s = ground_tex.shape[0]
    plane = np.array([[1.0, 0.0, -t[0]], [0.0, 1.0, -t[1]], [0.0, 0.0, -t[2]]])
    tex_to_img = k @ r.T @ plane @ np.diag([ground_tile_m / s, ground_tile_m / s, 1.0])
    shift = np.array([[1.0, 0.0, 0.5], [0.0, 1.0, 0.5], [0.0, 0.0, 1.0]])  # texel centres
    crop = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, -r0], [0.0, 0.0, 1.0]])  # rows r0:r1 only
    warped = cv2.warpPerspective(
        ground_tex, crop @ tex_to_img @ shift, (w, r1 - r0), flags=cv2.INTER_LINEAR,
        borderMode=cv2.BORDER_WRAP,
    )  # fmt: skip
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = np.float32(1.0) / dzs
        # Metres per pixel on the ground over a quarter tile, minus one: > 0 => fade to the mean.
        fade = norms[r0:r1] * inv
        fade *= inv
        fade *= np.float32(4.0 * t[2] / (k[0, 0] * ground_tile_m))
    fade -= 1.0
    np.clip(fade, 0.0, 1.0, out=fade)
    # Fade only the band of rows that needs it (near the horizon); then the light's gain.
    band = np.flatnonzero(fade.max(axis=1) > 0.0)
    if len(band):
        b0, b1 = int(band[0]), int(band[-1]) + 1
        mean = np.empty_like(warped[b0:b1])
        mean[:] = np.round(ground_tex.reshape(-1, 3).mean(axis=0)).astype(np.uint8)
        f = fade[b0:b1].astype(np.float32, copy=False)
        warped[b0:b1] = cv2.blendLinear(warped[b0:b1], mean, np.float32(1.0) - f, f)
    gain = tuple(float(x) for x in ground_gain) + (0.0,)
    cv2.copyTo(cv2.multiply(warped, gain), g.view(np.uint8), rgb[r0:r1])
    if shadow is not None:
        dark = np.logical_and(g, shadow[r0:r1].view(bool))
        if dark.any():
            gain = tuple(float(x) for x in shadow_gain) + (0.0,)
            cv2.copyTo(cv2.multiply(warped, gain), dark.view(np.uint8), rgb[r0:r1])
    seg[r0:r1][g] = GROUND_ID
    depth[r0:r1][g] = (np.float32(-t[2]) * inv)[g]


def blend_reflection(
    rgb: np.ndarray,
    floor: np.ndarray,
    mirror: np.ndarray,
    hit: np.ndarray,
    reflectivity: float,
    blur_px: float = 0.0,
) -> None:
    """Blend a glossy floor's reflection into the floor pixels, in place.

    A floor pixel whose reflection shows an object becomes ``(1 - k) * floor + k * reflection``,
    k = ``reflectivity``; the blur spreads the reflection's colour and its weight alike, so the
    pixels where the reflection shows nothing (sky, floor) neither darken nor change.

    Args:
        rgb: (H, W, 3) uint8 rendered image, modified.
        floor: (H, W) bool, the floor's pixels.
        mirror: (H, W, 3) uint8 render of the world mirrored through the floor, same camera.
        hit: (H, W) bool, where ``mirror`` shows an object.
        reflectivity: k in [0, 1].
        blur_px: Gaussian blur sigma of the reflection, pixels (0: sharp).
    """
    weight = hit.astype(np.float32)
    colour = mirror.astype(np.float32) * weight[..., None]
    if blur_px > 0.0:
        colour = cv2.GaussianBlur(colour, (0, 0), blur_px)
        weight = cv2.GaussianBlur(weight, (0, 0), blur_px)
    seen = floor & (weight > 1e-3)
    w = weight[seen][:, None]
    out = (1.0 - reflectivity * w) * rgb[seen] + reflectivity * colour[seen]
    rgb[seen] = np.clip(np.rint(out), 0, 255).astype(np.uint8)
