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
from icarus_vision.render.textures import Material
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
    return SceneStyle(
        gate_materials=gates,
        frame_width=_u(rng, g.frame_width),
        ground=sample_material(rng, recipe.ground),
        background=sample_material(rng, recipe.sky),
    )


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
    return replace(
        base,
        hfov_deg=_u(rng, c.hfov_deg),
        uptilt_deg=_u(rng, c.uptilt_deg),
        roll_deg=_u(rng, c.roll_deg),
    )


def sample_sensor(recipe: Recipe, rng: np.random.Generator) -> SensorNoise:
    """Noise, gamma, gain and blur of one image."""
    s = recipe.sensor
    noise, gamma, gain = _u(rng, s.noise_std), _u(rng, s.gamma), _u(rng, s.gain)
    blur = _u(rng, s.blur_sigma_px) if rng.random() < s.blur_prob else 0.0
    return SensorNoise(noise, gamma, gain, blur)


def sample_visuals(
    recipe: Recipe, rng: np.random.Generator, track: Track, base_camera: Camera | None = None
) -> Visuals:
    """Draw every random visual choice of one scene / frame, in a fixed order."""
    style = sample_style(recipe, rng, len(track.physical_gates()))
    distractors = sample_distractors(recipe, rng, track, style.gate_materials)
    lighting = sample_lighting(recipe, rng)
    camera = sample_camera(recipe, rng, base_camera or Camera())
    return Visuals(style, distractors, lighting, camera, sample_sensor(recipe, rng))


def apply_sensor_noise(rgb: np.ndarray, noise: SensorNoise, rng: np.random.Generator) -> np.ndarray:
    """Degrade an image: blur, gain and gamma, then additive Gaussian noise.

    Args:
        rgb: (H, W, 3) uint8.
        noise: the drawn degradations.
        rng: generator for the pixel noise.

    Returns:
        (H, W, 3) uint8 new image.
    """
    img = rgb
    if noise.blur_sigma_px > 0.0:
        img = cv2.GaussianBlur(img, (0, 0), noise.blur_sigma_px)
    if noise.gamma != 1.0 or noise.gain != 1.0:
        lut = np.clip(255.0 * noise.gain * (np.arange(256) / 255.0) ** noise.gamma, 0, 255)
        img = cv2.LUT(img, np.round(lut).astype(np.uint8))
    if noise.noise_std > 0.0:
        # OpenCV's normal generator, seeded from rng, is about 3x faster than numpy's here.
        img = np.ascontiguousarray(img)
        n = np.empty((img.shape[0], img[0].size), np.float32)
        cv2.setRNGSeed(int(rng.integers(2**31)))
        cv2.randn(n, 0.0, float(noise.noise_std))
        img = cv2.add(img.reshape(n.shape), n, dtype=cv2.CV_8U).reshape(img.shape)
    return np.ascontiguousarray(img)
