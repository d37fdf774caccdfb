"""COCO keypoint files of a dataset's splits, and summary statistics of its labels.

Schema (one file per split, ``annotations/<split>.json``): the standard COCO keys ``info``,
``licenses``, ``images``, ``annotations``, ``categories``. One category, ``gate`` (id 1), with
keypoints ``TL, TR, BR, BL`` (the inner opening's corners, ARCHITECTURE.md order) and the skeleton
of the opening's four sides. Annotations carry COCO ``keypoints`` (x, y, v; v = 2 visible, 1 in the
image but hidden, 0 outside), ``num_keypoints``, ``bbox``, ``area``, ``iscrowd``, plus ``gate_id``,
``passage``, ``distance`` (m), ``corners_px``, ``pixels`` and ``gate_pose`` (R, t of the gate in the
camera's OpenCV frame). Images carry the camera (``K``, FOV, uptilt, roll) and the body pose.
"""

from __future__ import annotations

import numpy as np

from icarus_vision.render.labels import HIDDEN, OUTSIDE, VISIBLE

KEYPOINTS = ("TL", "TR", "BR", "BL")
"""Keypoint names, in order."""
SKELETON = ((1, 2), (2, 3), (3, 4), (4, 1))
"""Sides of the opening, as 1-based keypoint index pairs (COCO convention)."""
CATEGORY = {
    "id": 1,
    "name": "gate",
    "supercategory": "gate",
    "keypoints": list(KEYPOINTS),
    "skeleton": [list(e) for e in SKELETON],
}
DISTANCE_BINS = (0.0, 1.0, 2.0, 4.0, 8.0, 16.0, 32.0)
"""Lower edges of the distance histogram bins, m (the last bin is open)."""


def split_json(records: list[dict], split: str, info: dict, first_ann_id: int) -> dict:
    """The COCO dict of one split from its shard records (in order).

    Args:
        records: shard records of this split.
        split: split name (recorded in ``info``).
        info: extra ``info`` fields (recipe name, seed, version ...).
        first_ann_id: id of the split's first annotation (ids are unique over the dataset).
    """
    images = [{k: v for k, v in im.items() if k != "sha256"} for r in records for im in r["images"]]
    anns = [
        {"id": first_ann_id + i, **a}
        for i, a in enumerate(a for r in records for a in r["annotations"])
    ]
    return {
        "info": {"description": f"icarus-vision gate keypoints ({split})", "split": split, **info},
        "licenses": [],
        "images": images,
        "annotations": anns,
        "categories": [CATEGORY],
    }


def _hist(values: np.ndarray, edges: tuple[float, ...]) -> dict[str, int]:
    out = {}
    for i, lo in enumerate(edges):
        hi = edges[i + 1] if i + 1 < len(edges) else np.inf
        key = f"{lo:g}-{hi:g}" if np.isfinite(hi) else f"{lo:g}+"
        out[key] = int(np.count_nonzero((values >= lo) & (values < hi)))
    return out


def summary_stats(records: list[dict]) -> dict:
    """Counts and distributions of a dataset's labels (for the manifest)."""
    images = [im for r in records for im in r["images"]]
    anns = [a for r in records for a in r["annotations"]]
    per_image = {im["id"]: 0 for im in images}
    for a in anns:
        per_image[a["image_id"]] += 1
    counts = np.array(list(per_image.values()), dtype=int)
    dist = np.array([a["distance"] for a in anns], dtype=float)
    flags = np.array([a["keypoints"][2::3] for a in anns], dtype=int).reshape(-1, 4)

    def q(p: float) -> float | None:
        return round(float(np.percentile(dist, p)), 3) if len(dist) else None

    return {
        "images": len(images),
        "annotations": len(anns),
        "images_without_gates": int(np.count_nonzero(counts == 0)),
        "gates_per_image": {
            "mean": round(float(counts.mean()), 3) if len(counts) else 0.0,
            "max": int(counts.max()) if len(counts) else 0,
            "histogram": {str(k): int(v) for k, v in enumerate(np.bincount(counts))},
        },
        "distance_m": {
            "min": q(0),
            "p05": q(5),
            "median": q(50),
            "mean": round(float(dist.mean()), 3) if len(dist) else None,
            "p95": q(95),
            "max": q(100),
            "histogram": _hist(dist, DISTANCE_BINS),
        },
        "keypoints": {
            "visible": int(np.count_nonzero(flags == VISIBLE)),
            "hidden": int(np.count_nonzero(flags == HIDDEN)),
            "outside": int(np.count_nonzero(flags == OUTSIDE)),
        },
        "gates_all_corners_visible": int(np.count_nonzero((flags == VISIBLE).all(axis=1))),
        "gates_partly_outside": int(
            np.count_nonzero((flags == OUTSIDE).any(axis=1) & (flags != OUTSIDE).any(axis=1))
        ),
    }
