"""The written labels: COCO keypoint schema (read with pycocotools), manifest, contact sheet, and
every corner marked visible lying on the gate's pixels of the segmentation."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from icarus_vision import __version__
from icarus_vision.dataset.layout import plan_shards
from icarus_vision.dataset.shard import annotation_dict, iter_samples
from icarus_vision.render.labels import HIDDEN, VISIBLE
from icarus_vision.render.recipe import load_recipe

from .conftest import TINY_IMAGES


def test_coco_files_load_with_pycocotools(reference):
    coco_mod = pytest.importorskip("pycocotools.coco")
    out, result = reference
    ann_ids = []
    for split, n in result.manifest["splits"].items():
        coco = coco_mod.COCO(str(out / "annotations" / f"{split}.json"))
        cat = coco.loadCats(coco.getCatIds(catNms=["gate"]))[0]
        assert cat["keypoints"] == ["TL", "TR", "BR", "BL"]
        assert cat["skeleton"] == [[1, 2], [2, 3], [3, 4], [4, 1]]
        assert len(coco.getImgIds()) == n
        for img in coco.loadImgs(coco.getImgIds()):
            assert (out / "images" / img["file_name"]).is_file()
            assert (img["width"], img["height"]) == (160, 120)
            assert np.asarray(img["camera"]["K"]).shape == (3, 3)
        for ann in coco.loadAnns(coco.getAnnIds()):
            kps = np.asarray(ann["keypoints"], dtype=float).reshape(4, 3)
            assert set(kps[:, 2]) <= {0, 1, 2}
            assert ann["num_keypoints"] == np.count_nonzero(kps[:, 2])
            assert np.all(kps[kps[:, 2] == 0, :2] == 0)
            x, y, w, h = ann["bbox"]
            assert w > 0 and h > 0 and ann["category_id"] == 1 and ann["iscrowd"] == 0
            assert ann["distance"] > 0 and len(ann["corners_px"]) == 4
            assert np.asarray(ann["gate_pose"]["R_cam_gate"]).shape == (3, 3)
            ann_ids.append(ann["id"])
    assert len(ann_ids) == len(set(ann_ids)) == result.manifest["stats"]["annotations"] > 0


def test_manifest_fields(reference):
    out, result = reference
    m = json.loads((out / "manifest.json").read_text())
    assert m == result.manifest
    assert m["seed"] == 3 and m["num_images"] == TINY_IMAGES and m["version"] == __version__
    assert m["splits"] == {"train": 8, "val": 4, "test": 4}
    assert m["recipe"]["name"] == "gates-v1" and m["recipe"]["dataset"]["shard_size"] == 4
    assert [s["name"] for s in m["shards"]] == ["train-0000", "train-0001", "val-0000", "test-0000"]
    assert all(s["count"] == 4 and s["checksum"].startswith("sha256:") for s in m["shards"])
    stats = m["stats"]
    assert stats["images"] == TINY_IMAGES
    assert sum(stats["gates_per_image"]["histogram"].values()) == TINY_IMAGES
    assert sum(stats["distance_m"]["histogram"].values()) == stats["annotations"]
    assert sum(stats["keypoints"].values()) == 4 * stats["annotations"]
    sheet = cv2.imread(str(out / "contact_sheet.png"))
    assert sheet.shape == (4 * 120, 4 * 160, 3)


def test_visible_corners_lie_on_gate_pixels(reference, tiny_recipe):
    out, _ = reference
    recipe = load_recipe(tiny_recipe)
    spec = plan_shards(TINY_IMAGES, recipe.dataset)[0]
    record = json.loads((out / "shards" / f"{spec.name}.json").read_text())
    counts = {VISIBLE: 0, HIDDEN: 0}
    written = iter(record["annotations"])
    for s in iter_samples(recipe, 3, spec):
        h, w = s.frame.seg.shape
        for lab in s.labels:
            assert annotation_dict(lab, s.image_id) == next(written)  # what was written
            body = s.gate_bodies[lab.gate_id]
            for (u, v), flag in zip(lab.corners_px, lab.visibility, strict=True):
                if flag in counts:
                    counts[flag] += 1
                if flag == VISIBLE:
                    c, r = int(round(u)), int(round(v))
                    window = s.frame.seg[max(r - 2, 0) : r + 3, max(c - 2, 0) : c + 3]
                    assert (window == body).any(), (s.image_id, lab.gate_id, (u, v))
    assert next(written, None) is None
    assert counts[VISIBLE] > 4
