"""Visual domain randomisation: draw a scene's look, light, camera and sensor noise from a Recipe.

Every draw takes a ``numpy.random.Generator`` and nothing else random, so the same seed gives the
same images. The recipe dataclasses and their TOML loader live in :mod:`icarus_vision.render.recipe`.
"""

from __future__ import annotations

import colorsys
import math
from dataclasses import dataclass, replace

import cv2
import numpy as np

from icarus_vision.render.camera import Camera
from icarus_vision.render.recipe import (
    GateRanges,
    Recipe,
    SurfaceRanges,
    load_recipe,
    recipe_from_dict,
)
from icarus_vision.render.scene import Distractor, Lighting, SceneStyle
from icarus_vision.render.style import Gloss, Hall, Trim
from icarus_vision.render.textures import PRINTED_KINDS, Material
from icarus_vision.sim.track import Track

__all__ = [
    "Recipe",
    "SensorNoise",
    "Visuals",
    "apply_sensor_noise",
    "load_recipe",
    "recipe_from_dict",
    "sample_camera",
    "sample_distractors",
    "sample_gloss",
    "sample_hall",
    "sample_lighting",
    "sample_sensor",
    "sample_style",
    "sample_visuals",
]


@dataclass(frozen=True)
class SensorNoise:
    """Degradations of one image (drawn by :func:`sample_sensor`)."""

    noise_std: float = 0.0
    """Additive Gaussian noise, 8-bit levels."""
    gamma: float = 1.0
    """Gamma exponent."""
    gain: float = 1.0
    """Brightness gain."""
    blur_sigma_px: float = 0.0
    """Gaussian blur sigma, pixels (0: none)."""
    exposure: float = 1.0
    """Exposure factor (2^ev)."""
    color_gains: tuple[float, float, float] = (1.0, 1.0, 1.0)
    """Per-channel gains (a colour cast)."""
    vignette: float = 0.0
    """Brightness lost at the image corners (0: none)."""
    motion_blur_px: float = 0.0
    """Motion blur length, pixels (0: none)."""
    motion_blur_deg: float = 0.0
    """Motion blur direction in the image, degrees."""
    defocus_px: float = 0.0
    """Defocus disc radius, pixels (0: none)."""
    bloom: float = 0.0
    """Bloom strength (0: none)."""
    jpeg_quality: int = 0
    """JPEG quality (0: no compression)."""


@dataclass(frozen=True)
class Visuals:
    """Everything random about how one frame looks."""

    style: SceneStyle
    """Materials of gates, ground and sky, and the bar width."""
    distractors: tuple[Distractor, ...]
    """Objects placed around the gates."""
    lighting: Lighting
    """The light of the frame."""
    camera: Camera
    """The jittered camera."""
    sensor: SensorNoise
    """Sensor degradations."""


def _u(rng: np.random.Generator, r) -> float:
    return float(rng.uniform(r[0], r[1])) if r[1] > r[0] else float(r[0])


def _hsv_color(rng, s: SurfaceRanges) -> tuple[tuple[float, ...], tuple[float, ...]]:
    h, sat, val = _u(rng, s.hue) % 1.0, _u(rng, s.saturation), _u(rng, s.value)
    c1 = colorsys.hsv_to_rgb(h, sat, val)
    dv = _u(rng, s.contrast)
    val2 = val - dv if val - dv >= 0.0 or val + dv > 1.0 else val + dv
    c2 = colorsys.hsv_to_rgb(h, sat, min(max(val2, 0.0), 1.0))
    return c1, c2


def _kind(rng, s: SurfaceRanges) -> str:
    w = np.asarray(s.kind_weights, dtype=float)
    return s.kinds[int(rng.choice(len(w), p=w / w.sum()))]


def _clip3(c) -> tuple[float, float, float]:
    return tuple(float(min(max(x, 0.0), 1.0)) for x in c)  # type: ignore[return-value]


def sample_material(rng: np.random.Generator, s: SurfaceRanges) -> Material:
    """A surface look drawn from HSV ranges."""
    c1, c2 = _hsv_color(rng, s)
    seed = int(rng.integers(2**31))
    return Material(_kind(rng, s), _clip3(c1), _clip3(c2), _u(rng, s.tile), seed)


def sample_gate_material(rng: np.random.Generator, g: GateRanges) -> Material:
    """A gate look: a jittered palette colour or, with ``random_color_prob``, an HSV one."""
    c1, c2 = _hsv_color(rng, g)
    if rng.random() >= g.random_color_prob:
        base = np.asarray(g.palette[int(rng.integers(len(g.palette)))])
        c1 = base + rng.uniform(-g.palette_jitter, g.palette_jitter, 3)
    seed = int(rng.integers(2**31))
    return Material(_kind(rng, g), _clip3(c1), _clip3(c2), _u(rng, g.tile), seed)


def sample_style(recipe: Recipe, rng: np.random.Generator, num_gates: int) -> SceneStyle:
    """Materials for ``num_gates`` physical gates, the ground and the sky, and the bar width."""
    g = recipe.gates
    n = 1 if rng.random() < g.same_look_prob else max(1, num_gates)
    gates = tuple(sample_gate_material(rng, g) for _ in range(n))
    style = SceneStyle(
        gate_materials=gates,
        frame_width=_u(rng, g.frame_width),
        ground=sample_material(rng, recipe.ground),
        background=sample_material(rng, recipe.sky),
    )
    # The later recipes' draws come after the first recipes' ones, and only where switched on,
    # so a recipe without them draws what it always drew.
    depth = _u(rng, g.depth) if g.depth[1] > 0.0 else None
    trim = None
    if g.trim_prob > 0.0 and rng.random() < g.trim_prob:
        base = np.asarray(g.trim_palette[int(rng.integers(len(g.trim_palette)))])
        colour = _clip3(base + rng.uniform(-g.palette_jitter, g.palette_jitter, 3))
        trim = Trim(
            Material("solid", colour), _u(rng, g.trim_width), rng.random() < g.trim_led_prob
        )
    return replace(style, frame_depth=depth, trim=trim)


def sample_distractors(
    recipe: Recipe, rng: np.random.Generator, track: Track, gate_materials: tuple[Material, ...]
) -> tuple[Distractor, ...]:
    """Distractor objects around randomly chosen gates (never inside an opening's 1.5 m radius)."""
    d = recipe.distractors
    n = int(rng.integers(d.count[0], d.count[1] + 1))
    gates = track.physical_gates()
    out = []
    for _ in range(n):
        gate = gates[int(rng.integers(len(gates)))]
        ang = rng.uniform(0.0, 2.0 * math.pi)
        r = max(_u(rng, d.distance), 1.5)
        size = _u(rng, d.size)
        x, y = gate.pos[0] + r * math.cos(ang), gate.pos[1] + r * math.sin(ang)
        yaw = float(rng.uniform(-180.0, 180.0))
        if rng.random() < d.gate_like_prob:
            shape = "arch" if rng.random() < 0.5 else "frame"
            w, h = size * rng.uniform(0.5, 1.5), size * rng.uniform(0.5, 1.5)
            if shape == "frame" and abs(w - h) < 0.25 * max(w, h):
                h = w * (1.6 if rng.random() < 0.5 else 0.6)  # never a square: squares are gates
            bar = float(rng.uniform(0.04, 0.2))
            mat = gate_materials[int(rng.integers(len(gate_materials)))]
            z = max(_u(rng, d.height), h / 2 + bar)
            out.append(Distractor(shape, (x, y, z), (w, h, bar), yaw, mat))
            continue
        if d.extra_prob > 0.0 and rng.random() < d.extra_prob:
            out.append(_extra_distractor(recipe, rng, (x, y), yaw))
            continue
        shape = ("box", "cylinder", "sphere", "pole")[int(rng.integers(4))]
        mat = sample_material(rng, recipe.ground)
        if shape == "box":
            ext = tuple(size * rng.uniform(0.3, 1.0, 3))
            z = max(_u(rng, d.height), ext[2] / 2)
        elif shape == "sphere":
            ext = (size / 2, size / 2, size / 2)
            z = max(_u(rng, d.height), size / 2)
        else:
            rad = size * (0.05 if shape == "pole" else 0.25)
            length = size * (3.0 if shape == "pole" else 1.0)
            ext, z = (rad, rad, length), length / 2
        out.append(Distractor(shape, (x, y, float(z)), tuple(map(float, ext)), yaw, mat))
    return tuple(out)


def _extra_distractor(recipe: Recipe, rng: np.random.Generator, xy, yaw: float) -> Distractor:
    """A person, tree, net, banner or screen (``distractors.extra_shapes``) standing at ``xy``."""
    d = recipe.distractors
    shape = d.extra_shapes[int(rng.integers(len(d.extra_shapes)))]
    x, y = xy
    if shape == "person":
        h = float(rng.uniform(1.5, 1.9))
        clothes = sample_material(rng, recipe.ground)
        skin = Material("solid", _clip3(rng.uniform([0.35, 0.2, 0.12], [0.95, 0.75, 0.6])))
        return Distractor(shape, (x, y, h / 2), (float(rng.uniform(0.35, 0.55)), 0.0, h), yaw,
                          clothes, skin)  # fmt: skip
    if shape == "tree":
        h = float(rng.uniform(2.5, 8.0))
        bark = Material(
            "noise", (0.35, 0.22, 0.12), (0.2, 0.12, 0.06), 0.5, int(rng.integers(2**31))
        )
        leaves = Material("noise", _clip3(rng.uniform([0.05, 0.25, 0.02], [0.35, 0.6, 0.2])),
                          _clip3(rng.uniform([0.0, 0.1, 0.0], [0.15, 0.35, 0.1])), 0.8,
                          int(rng.integers(2**31)))  # fmt: skip
        return Distractor(shape, (x, y, h / 2), (h * float(rng.uniform(0.25, 0.45)), 0.0, h),
                          yaw, bark, leaves)  # fmt: skip
    if shape == "net":
        w, h = float(rng.uniform(3.0, 12.0)), float(rng.uniform(2.0, 6.0))
        colour = _clip3(rng.uniform(0.0, 0.25, 3) if rng.random() < 0.6 else rng.uniform(0, 1, 3))
        return Distractor(shape, (x, y, h / 2), (w, h, float(rng.uniform(0.1, 0.4))), yaw,
                          Material("solid", colour))  # fmt: skip
    if shape == "screen":
        return _screen(recipe, rng, xy, yaw)
    w, h = float(rng.uniform(1.0, 4.0)), float(rng.uniform(0.4, 1.5))
    kind = PRINTED_KINDS[int(rng.integers(len(PRINTED_KINDS)))]
    c1, c2 = _hsv_color(rng, recipe.gates)
    board = Material(kind, _clip3(c1), _clip3(np.subtract(1.0, c1)), max(w, h) / 2,
                     int(rng.integers(2**31)))  # fmt: skip
    z = h / 2 + float(rng.uniform(0.0, 2.5))
    return Distractor("banner", (x, y, z), (w, h, 0.03), yaw, board)


def _screen(recipe: Recipe, rng: np.random.Generator, xy, yaw: float) -> Distractor:
    """A monitor, window, door or whiteboard: a filled rectangle, square or not (the rectangles
    of real rooms a detector must not take for gates), in a thin grey, black or white bezel."""
    w = float(rng.uniform(0.4, 2.5))
    h = w * float(rng.uniform(0.55, 1.8))
    bezel = w * float(rng.uniform(0.015, 0.12))
    grey = float(rng.uniform(0.0, 0.3) if rng.random() < 0.6 else rng.uniform(0.6, 1.0))
    frame = Material("solid", _clip3(grey + rng.uniform(-0.03, 0.03, 3)))
    c1, c2 = _hsv_color(rng, recipe.gates)
    kind = ("solid", "noise", "stripes", *PRINTED_KINDS)[int(rng.integers(5))]
    if kind == "solid" and rng.random() < 0.5:  # a switched-off screen, or a lit window
        c1 = tuple(
            _clip3(rng.uniform(0.0, 0.12, 3) if rng.random() < 0.5 else rng.uniform(0.8, 1, 3))
        )
    panel = Material(kind, _clip3(c1), _clip3(c2), max(w, h) / float(rng.uniform(1.0, 4.0)),
                     int(rng.integers(2**31)))  # fmt: skip
    z = h / 2 + bezel + float(rng.uniform(0.0, 2.5))
    return Distractor("screen", (xy[0], xy[1], z), (w, h, bezel), yaw, frame, panel)


def sample_hall(recipe: Recipe, rng: np.random.Generator, track: Track) -> Hall | None:
    """An indoor hall around ``track`` with probability ``hall.prob`` (no draw when it is 0)."""
    hr = recipe.hall
    if hr.prob <= 0.0 or rng.random() >= hr.prob:
        return None
    xy = np.array([g.pos[:2] for g in track.physical_gates()] + [track.start_pos[:2]], float)
    lo, hi = xy.min(axis=0) - _u(rng, hr.margin), xy.max(axis=0) + _u(rng, hr.margin)
    height = _u(rng, hr.height)
    walls, ceiling = sample_material(rng, recipe.ground), sample_material(rng, recipe.sky)
    n = int(rng.integers(hr.lights[0], hr.lights[1] + 1))
    side = float(rng.uniform(0.4, 1.5))
    lights = tuple((float(rng.uniform(lo[0], hi[0])), float(rng.uniform(lo[1], hi[1])), side)
                   for _ in range(n))  # fmt: skip
    trusses = bool(rng.random() < hr.truss_prob)
    banners = []
    for _ in range(int(rng.integers(hr.banners[0], hr.banners[1] + 1))):
        kind = PRINTED_KINDS[int(rng.integers(len(PRINTED_KINDS)))]
        c1, c2 = _hsv_color(rng, recipe.gates)
        w, h = float(rng.uniform(1.5, 6.0)), float(rng.uniform(0.5, 2.0))
        look = Material(kind, _clip3(c1), _clip3(np.subtract(1.0, c1)), max(w, h) / 2,
                        int(rng.integers(2**31)))  # fmt: skip
        banners.append((int(rng.integers(4)), float(rng.uniform(0.1, 0.9)),
                        float(rng.uniform(1.0, max(1.5, height - h))), w, h, look))  # fmt: skip
    return Hall(tuple(map(float, lo)), tuple(map(float, hi)), height, walls, ceiling, lights,
                trusses, tuple(banners))  # fmt: skip


def sample_gloss(recipe: Recipe, rng: np.random.Generator) -> Gloss | None:
    """A hall's glossy floor with probability ``hall.floor_gloss_prob`` (none when it is 0).

    Drawn from a stream jumped far ahead of ``rng``'s (``bit_generator.jumped()``), which leaves
    ``rng`` where it was: switching glossy floors on changes no other draw of a dataset.
    """
    hr = recipe.hall
    if hr.floor_gloss_prob <= 0.0:
        return None
    side = np.random.Generator(rng.bit_generator.jumped())
    if side.random() >= hr.floor_gloss_prob:
        return None
    return Gloss(_u(side, hr.floor_reflectivity), _u(side, hr.floor_blur_px))


def sample_lighting(recipe: Recipe, rng: np.random.Generator) -> Lighting:
    """Light direction, colour, strengths and the shadow switch."""
    li = recipe.light
    el, az = math.radians(_u(rng, li.elevation_deg)), math.radians(_u(rng, li.azimuth_deg))
    direction = (math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el))
    color = tuple(float(1.0 - x) for x in rng.uniform(0.0, li.color_jitter, 3))
    return Lighting(
        direction=direction,
        color=color,
        ambient=_u(rng, li.ambient),
        diffuse=_u(rng, li.diffuse),
        specular=_u(rng, li.specular),
        shadows=bool(rng.random() < li.shadow_prob),
    )


def sample_camera(recipe: Recipe, rng: np.random.Generator, base: Camera) -> Camera:
    """The base camera with FOV, uptilt and roll drawn from the recipe (resolution kept)."""
    c = recipe.camera
    cam = replace(
        base,
        hfov_deg=_u(rng, c.hfov_deg),
        uptilt_deg=_u(rng, c.uptilt_deg),
        roll_deg=_u(rng, c.roll_deg),
    )
    if c.distortion_prob > 0.0 and rng.random() < c.distortion_prob:
        if rng.random() < c.fisheye_prob:
            coeffs = (_u(rng, c.fisheye_k1), float(rng.uniform(-0.02, 0.02)), 0.0, 0.0)
            cam = replace(cam, distortion="fisheye", dist_coeffs=coeffs)
        else:
            k1, k2 = _u(rng, c.radtan_k1), _u(rng, c.radtan_k2)
            p1, p2 = (float(x) for x in rng.uniform(-0.002, 0.002, 2))
            cam = replace(cam, distortion="radtan", dist_coeffs=(k1, k2, p1, p2))
    if c.aspect_prob > 0.0 and rng.random() < c.aspect_prob:
        a = float(c.aspects[int(rng.integers(len(c.aspects)))])
        if a >= base.width / base.height:
            cam = replace(cam, height=max(8, int(round(base.width / a))))
        else:
            cam = replace(cam, width=max(8, int(round(base.height * a))))
    return cam


def sample_sensor(recipe: Recipe, rng: np.random.Generator) -> SensorNoise:
    """Noise, gamma, gain and blur of one image."""
    s = recipe.sensor
    noise, gamma, gain = _u(rng, s.noise_std), _u(rng, s.gamma), _u(rng, s.gain)
    blur = _u(rng, s.blur_sigma_px) if rng.random() < s.blur_prob else 0.0
    out = SensorNoise(noise, gamma, gain, blur)
    # The later recipes' effects: drawn only where switched on (the first recipes draw as before).
    later = {}
    if s.exposure_ev != (0.0, 0.0):
        later["exposure"] = float(2.0 ** _u(rng, s.exposure_ev))
    if s.color_cast > 0.0:
        later["color_gains"] = tuple(float(g) for g in 1.0 + rng.uniform(-1, 1, 3) * s.color_cast)

    def maybe(prob: float, r) -> float:
        return _u(rng, r) if prob > 0.0 and rng.random() < prob else 0.0

    later["vignette"] = maybe(s.vignette_prob, s.vignette)
    later["motion_blur_px"] = maybe(s.motion_blur_prob, s.motion_blur_px)
    if later["motion_blur_px"] > 0.0:
        later["motion_blur_deg"] = float(rng.uniform(0.0, 180.0))
    later["defocus_px"] = maybe(s.defocus_prob, s.defocus_px)
    later["bloom"] = maybe(s.bloom_prob, s.bloom)
    later["jpeg_quality"] = int(round(maybe(s.jpeg_prob, s.jpeg_quality)))
    return replace(out, **later)


def sample_visuals(
    recipe: Recipe, rng: np.random.Generator, track: Track, base_camera: Camera | None = None
) -> Visuals:
    """Draw every random visual choice of one scene / frame, in a fixed order."""
    style = sample_style(recipe, rng, len(track.physical_gates()))
    distractors = sample_distractors(recipe, rng, track, style.gate_materials)
    lighting = sample_lighting(recipe, rng)
    camera = sample_camera(recipe, rng, base_camera or Camera())
    sensor = sample_sensor(recipe, rng)
    hall = sample_hall(recipe, rng, track)
    if hall is not None:
        style = replace(style, hall=hall, gloss=sample_gloss(recipe, rng))
    return Visuals(style, distractors, lighting, camera, sensor)


def apply_sensor_noise(rgb: np.ndarray, noise: SensorNoise, rng: np.random.Generator) -> np.ndarray:
    """Degrade an image: bloom, defocus, motion blur, blur, exposure and colour cast, gain and
    gamma, vignetting, additive Gaussian noise, then JPEG compression (each where drawn).

    Args:
        rgb: (H, W, 3) uint8.
        noise: the drawn degradations.
        rng: generator for the pixel noise.

    Returns:
        (H, W, 3) uint8 new image.
    """
    img = rgb
    if noise.bloom > 0.0:  # the brightest parts glow
        bright = cv2.threshold(img, 200, 255, cv2.THRESH_TOZERO)[1]
        glow = cv2.GaussianBlur(bright, (0, 0), 0.02 * max(img.shape[:2]))
        img = cv2.addWeighted(img, 1.0, glow, noise.bloom, 0.0)
    if noise.defocus_px > 0.0:
        r = noise.defocus_px
        n = 2 * int(math.ceil(r)) + 1
        disc = cv2.circle(np.zeros((n, n), np.float32), (n // 2, n // 2), int(round(r)), 1.0, -1)
        img = cv2.filter2D(img, -1, disc / disc.sum(), borderType=cv2.BORDER_REFLECT)
    if noise.motion_blur_px > 0.0:
        n = 2 * int(math.ceil(noise.motion_blur_px / 2)) + 1
        line = np.zeros((n, n), np.float32)
        line[n // 2, :] = 1.0
        turn = cv2.getRotationMatrix2D((n / 2 - 0.5, n / 2 - 0.5), noise.motion_blur_deg, 1.0)
        line = cv2.warpAffine(line, turn, (n, n))
        img = cv2.filter2D(img, -1, line / line.sum(), borderType=cv2.BORDER_REFLECT)
    if noise.blur_sigma_px > 0.0:
        img = cv2.GaussianBlur(img, (0, 0), noise.blur_sigma_px)
    if noise.exposure != 1.0 or noise.color_gains != (1.0, 1.0, 1.0):
        gains = noise.exposure * np.asarray(noise.color_gains, np.float32)
        img = cv2.multiply(img.astype(np.float32), gains.reshape(1, 1, 3), dtype=cv2.CV_32F)
        img = np.clip(img, 0, 255).astype(np.uint8)
    if noise.gamma != 1.0 or noise.gain != 1.0:
        lut = np.clip(255.0 * noise.gain * (np.arange(256) / 255.0) ** noise.gamma, 0, 255)
        img = cv2.LUT(img, np.round(lut).astype(np.uint8))
    if noise.vignette > 0.0:
        h, w = img.shape[:2]
        yy, xx = np.ogrid[:h, :w]
        r2 = ((xx - (w - 1) / 2) ** 2 + (yy - (h - 1) / 2) ** 2) / (
            ((w - 1) / 2) ** 2 + ((h - 1) / 2) ** 2
        )
        gain = (1.0 - noise.vignette * r2).astype(np.float32)[..., None]
        img = np.clip(img * gain, 0, 255).astype(np.uint8)
    if noise.noise_std > 0.0:
        # OpenCV's normal generator, seeded from rng, is about 3x faster than numpy's here.
        img = np.ascontiguousarray(img)
        n = np.empty((img.shape[0], img[0].size), np.float32)
        cv2.setRNGSeed(int(rng.integers(2**31)))
        cv2.randn(n, 0.0, float(noise.noise_std))
        img = cv2.add(img.reshape(n.shape), n, dtype=cv2.CV_8U).reshape(img.shape)
    if noise.jpeg_quality > 0:
        ok, buf = cv2.imencode(".jpg", np.ascontiguousarray(img), [cv2.IMWRITE_JPEG_QUALITY,
                                                                   noise.jpeg_quality])  # fmt: skip
        img = cv2.imdecode(buf, cv2.IMREAD_UNCHANGED) if ok else img
    return np.ascontiguousarray(img)
