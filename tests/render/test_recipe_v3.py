"""The gates-v3 recipe (real gates and places): its new draws stay in their ranges, are seeded,
leave the first recipes' draws alone, and render what they promise (LED trims that count as the
gate, letterboxed frames, halls)."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from icarus_vision.dataset import generate_dataset
from icarus_vision.render.camera import PAD_VALUE, Camera
from icarus_vision.render.labels import VISIBLE, frame_labels
from icarus_vision.render.randomize import (
    apply_sensor_noise,
    load_recipe,
    recipe_from_dict,
    sample_sensor,
    sample_visuals,
)
from icarus_vision.render.recipe_sections import LATER_KEYS
from icarus_vision.render.scene import Scene
from icarus_vision.render.style import Distractor, SceneStyle, Trim
from icarus_vision.render.textures import Material, texture_image
from icarus_vision.sim.random_track import random_track
from icarus_vision.sim.track import Gate, Track

ROOT = Path(__file__).resolve().parents[2]
V1, V3 = ROOT / "datasets" / "gates-v1.toml", ROOT / "datasets" / "gates-v3.toml"
LEVEL = np.array([0.0, 0.0, 0.0, 1.0])
EYE = np.array([0.0, 0.0, 2.0])


def test_the_first_recipe_keeps_its_identity():
    d = load_recipe(V1).to_dict()
    for section, keys in LATER_KEYS.items():
        assert not set(keys) & set(d.get(section, {}))
    assert "hall" not in d
    v3 = load_recipe(V3).to_dict()
    assert set(LATER_KEYS["sensor"]) <= set(v3["sensor"])
    assert not set(LATER_KEYS["hall"]) & set(v3["hall"])  # gates-v4's glossy floors
    assert set(LATER_KEYS["hall"]) <= set(load_recipe("gates-v4").to_dict()["hall"])


def test_v3_draws_stay_in_their_ranges_and_repeat_with_the_seed():
    recipe = load_recipe(V3)
    track = random_track(5, seed=3)
    seen = {"trim": 0, "led": 0, "hall": 0, "lens": 0, "aspect": 0, "extra": 0, "jpeg": 0}
    for seed in range(60):
        v = sample_visuals(recipe, np.random.default_rng(seed), track, Camera())
        again = sample_visuals(recipe, np.random.default_rng(seed), track, Camera())
        assert v == again
        g = recipe.gates
        assert g.frame_width[0] <= v.style.frame_width <= g.frame_width[1]
        assert g.depth[0] <= v.style.frame_depth <= g.depth[1]
        if v.style.trim is not None:
            seen["trim"] += 1
            seen["led"] += v.style.trim.led
            assert g.trim_width[0] <= v.style.trim.width <= g.trim_width[1]
        if v.style.hall is not None:
            seen["hall"] += 1
            lo, hi = np.array(v.style.hall.lo), np.array(v.style.hall.hi)
            gates = np.array([q.pos[:2] for q in track.physical_gates()])
            assert (gates > lo + 1.9).all() and (gates < hi - 1.9).all()
            assert recipe.hall.height[0] <= v.style.hall.height <= recipe.hall.height[1]
        cam = v.camera
        if cam.distorted:
            seen["lens"] += 1
            k1 = cam.dist_coeffs[0]
            lo1, hi1 = (
                recipe.camera.fisheye_k1 if cam.distortion == "fisheye" else recipe.camera.radtan_k1
            )
            assert lo1 <= k1 <= hi1
        if (cam.width, cam.height) != (320, 240):
            seen["aspect"] += 1
            assert cam.width <= 320 and cam.height <= 240
            assert min(abs(cam.width / cam.height - a) for a in recipe.camera.aspects) < 0.02
        seen["extra"] += sum(d.shape in ("person", "tree", "net", "banner") for d in v.distractors)
        s = v.sensor
        seen["jpeg"] += s.jpeg_quality > 0
        assert 2.0**-1.2 - 1e-9 <= s.exposure <= 2.0 + 1e-9
        assert all(abs(x - 1.0) <= 0.12 + 1e-9 for x in s.color_gains)
        assert s.jpeg_quality == 0 or 25 <= s.jpeg_quality <= 95
    assert all(n >= 3 for n in seen.values()), seen


def test_every_sensor_effect_changes_the_image_and_keeps_its_shape():
    rng = np.random.default_rng(0)
    img = np.zeros((60, 80, 3), np.uint8)
    img[20:40, 30:50] = (250, 240, 230)
    img[:, :10] = 120
    base = sample_sensor(load_recipe(V1), np.random.default_rng(0))
    base = replace(base, noise_std=0.0, gamma=1.0, gain=1.0, blur_sigma_px=0.0)
    for effect in [{"exposure": 0.5}, {"color_gains": (1.1, 0.9, 1.0)}, {"vignette": 0.5},
                   {"motion_blur_px": 7.0, "motion_blur_deg": 30.0}, {"defocus_px": 2.0},
                   {"bloom": 0.8}, {"jpeg_quality": 20}]:  # fmt: skip
        out = apply_sensor_noise(img, replace(base, **effect), rng)
        assert out.shape == img.shape and out.dtype == np.uint8
        assert np.abs(out.astype(int) - img).max() > 3, effect
    np.testing.assert_array_equal(apply_sensor_noise(img, base, rng), img)


@pytest.mark.parametrize("kind", ["text", "logo"])
def test_printed_patterns_are_seeded_two_colour_marks(kind):
    a = texture_image(Material(kind, (1.0, 1.0, 1.0), (0.0, 0.0, 0.5), 0.5, 7))
    b = texture_image(Material(kind, (1.0, 1.0, 1.0), (0.0, 0.0, 0.5), 0.5, 7))
    c = texture_image(Material(kind, (1.0, 1.0, 1.0), (0.0, 0.0, 0.5), 0.5, 8))
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)
    inked = (a[..., 2] > 100) & (a[..., 0] < 60)
    assert 0.02 < inked.mean() < 0.8


def test_an_led_trim_glows_and_counts_as_its_gate():
    track = Track("one", (Gate((4.0, 0.0, 2.0)),), start_pos=(0.0, 0.0, 0.2))
    dark = Material("solid", (0.1, 0.1, 0.1))
    led = Trim(Material("solid", (0.2, 1.0, 0.4)), 0.05, led=True)
    style = SceneStyle(gate_materials=(dark,), frame_width=0.3, frame_depth=0.04, trim=led)
    grey = Material("solid", (0.4, 0.4, 0.4))
    box = Distractor("box", (6.0, -1.5, 2.0), (0.5, 0.5, 0.5), 0.0, grey)  # built after the trim
    with Scene(track, Camera(uptilt_deg=0.0), style, (box,)) as scene:
        frame = scene.render(EYE, LEVEL)
        (lab,) = frame_labels(scene, frame, EYE, LEVEL)
        body = scene.gate_bodies[0]
        (box_body,) = scene.distractor_bodies
    box_px = frame.rgb[frame.seg == box_body]
    assert len(box_px) > 20 and box_px[:, 1].max() < 200  # not lit like the LED
    assert list(lab.visibility) == [VISIBLE] * 4
    u, v = np.round(lab.corners_px[0]).astype(int)
    near = frame.rgb[v - 3 : v, u - 3 : u].reshape(-1, 3)  # on the trim, just outside the corner
    assert (near[:, 1] > 200).any() and (frame.seg[v - 3 : v, u - 3 : u] == body).any()
    assert frame.rgb[frame.seg == body][:, 1].max() == 255  # lit whatever the light
    assert set(np.unique(frame.seg)) <= {body, box_body, -1, -2}  # the trim's body never shows


def test_letterboxed_v3_frames_and_labels(tmp_path):
    """A v3 dataset where every camera has another aspect: frames padded with the detector's
    grey at the right or bottom, labels inside the camera's part, the same bytes again."""
    text = V3.read_text().replace("aspect_prob = 0.3", "aspect_prob = 1.0")
    text = text.split("[dataset]")[0] + "[dataset]\nwidth = 160\nheight = 120\nshard_size = 4\n"
    recipe = tmp_path / "wide.toml"
    recipe.write_text(text)
    generate_dataset(recipe, tmp_path / "a", 8, workers=1, seed=2)
    generate_dataset(recipe, tmp_path / "b", 8, workers=1, seed=2)
    import json

    import cv2

    coco = json.loads((tmp_path / "a" / "annotations" / "train.json").read_text())
    for im in coco["images"]:
        assert (im["width"], im["height"]) == (160, 120)
        w, h = im["camera"]["frame_px"]
        assert (w, h) != (160, 120) and w <= 160 and h <= 120
        a = cv2.imread(str(tmp_path / "a" / "images" / im["file_name"]))
        b = cv2.imread(str(tmp_path / "b" / "images" / im["file_name"]))
        np.testing.assert_array_equal(a, b)
        assert (a[h:] == PAD_VALUE).all() and (a[:, w:] == PAD_VALUE).all()
    for ann in coco["annotations"]:
        frame = next(
            im["camera"]["frame_px"] for im in coco["images"] if im["id"] == ann["image_id"]
        )
        xy = np.array(ann["keypoints"]).reshape(4, 3)
        seen = xy[xy[:, 2] > 0]
        assert (seen[:, 0] < frame[0]).all() and (seen[:, 1] < frame[1]).all()


@pytest.mark.parametrize(
    "section, key, value, needle",
    [
        ("distractors", "extra_shapes", ["person", "dog"], "person, tree, net, banner"),
        ("sensor", "jpeg_quality", [0.0, 90.0], "[1, 100]"),
        ("camera", "aspects", [0.0], "ratios"),
        ("gates", "trim_prob", 1.5, "probability"),
        ("hall", "height", [1.0, 3.0], "higher than 2 m"),
        ("hall", "floor_gloss_prob", 1.2, "probability"),
        ("hall", "floor_reflectivity", [0.2, 1.5], "must lie in [0, 1]"),
        ("hall", "floor_reflectivity", [0.5, 0.2], "low must be <= high"),
        ("hall", "floor_blur_px", [-1.0, 1.0], ">= 0"),
        ("gates", "kinds", ["solid", "graffiti"], "unknown kind"),
    ],
)
def test_bad_v3_values_name_the_key(section, key, value, needle):
    with pytest.raises(ValueError) as e:
        recipe_from_dict({section: {key: value}}, source="r.toml")
    assert needle in str(e.value) and f"{section}.{key}" in str(e.value)
