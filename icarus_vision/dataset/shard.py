"""Render, label, write and verify one shard of a dataset.

A shard's record (``shards/<name>.json``) holds the COCO image entries (with each PNG's SHA-256)
and the annotations of its images, and a checksum over all of it. It is written after the images,
atomically, so a record that exists and whose checksum matches the record and the files on disk
means the shard is complete.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from icarus_vision.dataset.layout import IMAGES, ShardSpec, image_file_name, shard_path
from icarus_vision.fileio import atomic_write_bytes
from icarus_vision.render.camera import PAD_VALUE, Camera
from icarus_vision.render.labels import OUTSIDE, GateLabel, frame_labels
from icarus_vision.render.poses import sample_poses, sample_track
from icarus_vision.render.randomize import (
    apply_sensor_noise,
    sample_lighting,
    sample_sensor,
    sample_visuals,
)
from icarus_vision.render.recipe import Recipe
from icarus_vision.render.scene import Frame, Scene


@dataclass(frozen=True)
class Sample:
    """One generated image with everything known about it.

    Attributes:
        image_id: dataset-wide id (from 1).
        rgb: (H, W, 3) uint8 final image (after sensor noise).
        frame: the clean render: rgb, seg (H, W) body ids, depth (H, W) m.
        labels: gate labels, nearest first.
        camera: the camera that rendered it.
        pos: (3,) body position, world, m; quat: (4,) body attitude x, y, z, w.
        target: index in the track's gates of the gate approached, -1 for a no-gate frame.
        scene: ``<shard>/<k>``, the scene (track, look, camera) the frame belongs to.
        gate_bodies: body id of each physical gate in ``frame.seg``.
    """

    image_id: int
    rgb: np.ndarray
    frame: Frame
    labels: list[GateLabel]
    camera: Camera
    pos: np.ndarray
    quat: np.ndarray
    target: int
    scene: str
    gate_bodies: tuple[int, ...]


def iter_samples(
    recipe: Recipe, seed: int, spec: ShardSpec, renderer: str = "tiny"
) -> Iterator[Sample]:
    """Generate a shard's samples in order, from the shard's own random stream.

    Every ``recipe.dataset.frames_per_scene`` frames a new scene is drawn: a random track, its look,
    distractors and camera; then per frame a pose, the light and the sensor noise.

    Args:
        renderer: ``"tiny"`` or ``"egl"`` (:data:`~icarus_vision.render.scene.RENDERERS`).

    Raises:
        RuntimeError: the renderer cannot run here (EGL: the plugin does not load).
    """
    rng = spec.rng(seed)
    ds = recipe.dataset
    base = Camera(width=ds.width, height=ds.height)
    ids = list(spec.image_ids)
    for k, start in enumerate(range(0, len(ids), ds.frames_per_scene)):
        scene_ids = ids[start : start + ds.frames_per_scene]
        track = sample_track(recipe.tracks, rng)
        vis = sample_visuals(recipe, rng, track, base)
        poses = sample_poses(recipe.poses, rng, track, vis.camera, len(scene_ids))
        with Scene(track, vis.camera, vis.style, vis.distractors, egl=renderer == "egl") as scene:
            if scene.renderer != renderer:  # a dataset never mixes renderers
                raise RuntimeError(
                    f"cannot render with {renderer!r} here (PyBullet's EGL plugin did not load); "
                    "use the tiny renderer"
                )
            for i, image_id in enumerate(scene_ids):
                pos, quat = poses.pos[i], poses.quat[i]
                frame = scene.render(pos, quat, sample_lighting(recipe, rng))
                labels = frame_labels(scene, frame, pos, quat, back_views=True)
                rgb = apply_sensor_noise(frame.rgb, sample_sensor(recipe, rng), rng)
                rgb = letterbox_into(rgb, (ds.width, ds.height))
                yield Sample(
                    image_id=image_id,
                    rgb=rgb,
                    frame=frame,
                    labels=labels,
                    camera=vis.camera,
                    pos=pos,
                    quat=quat,
                    target=int(poses.target[i]),
                    scene=f"{spec.name}/{k}",
                    gate_bodies=scene.gate_bodies,
                )


def letterbox_into(rgb: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """A frame of a camera smaller than the dataset's (another aspect ratio) placed at the
    top-left of a ``size`` (W, H) frame of the detector's padding grey, as the detector
    letterboxes such a camera's frames (labels keep their pixels); other frames as they are."""
    h, w = rgb.shape[:2]
    if (w, h) == tuple(size):
        return rgb
    out = np.full((size[1], size[0], 3), PAD_VALUE, np.uint8)
    out[:h, :w] = rgb
    return out


def _r(x, nd: int = 3):
    """Rounded float, or nested lists of them, for JSON; NaN becomes None."""
    a = np.round(np.asarray(x, dtype=float), nd)
    if np.isfinite(a).all():
        return a.tolist()
    return np.where(np.isfinite(a), a, None).tolist()


def annotation_dict(label: GateLabel, image_id: int) -> dict:
    """COCO keypoint annotation of one gate (without ``id``; assigned when a split is written).

    ``keypoints`` follows COCO: (x, y, v) per corner TL, TR, BR, BL, with x = y = 0 where v = 0.
    ``corners_px`` keeps every corner's projection (None behind the camera), in or out of frame.
    A gate seen from behind has ``passage`` None, ``from_behind`` true and its corners named as
    seen from that side (:mod:`icarus_vision.render.labels`).
    """
    kps = []
    for (u, v), flag in zip(label.corners_px, label.visibility, strict=True):
        kps += [0.0, 0.0, 0] if flag == OUTSIDE else [_r(u), _r(v), int(flag)]
    x, y, w, h = label.bbox
    return {
        "image_id": image_id,
        "category_id": 1,
        "keypoints": kps,
        "num_keypoints": int(np.count_nonzero(label.visibility)),
        "bbox": _r([x, y, w, h]),
        "area": _r(w * h),
        "iscrowd": 0,
        "gate_id": label.gate_id,
        "passage": label.passage,
        "from_behind": label.from_behind,
        "distance": _r(label.distance, 4),
        "corners_px": [_r(c) if np.all(np.isfinite(c)) else None for c in label.corners_px],
        "pixels": label.pixels,
        "gate_pose": {"R_cam_gate": _r(label.r_cam_gate, 6), "t_cam_gate": _r(label.t_cam_gate, 4)},
    }


def image_dict(sample: Sample) -> dict:
    """COCO image entry, with the camera and the body pose that made it."""
    cam = sample.camera
    lens = (
        {"distortion": cam.distortion, "dist_coeffs": _r(cam.dist_coeffs, 6)}
        if cam.distorted
        else {}
    )
    if (cam.width, cam.height) != sample.rgb.shape[1::-1]:
        lens["frame_px"] = [cam.width, cam.height]  # letterboxed: the camera's own frame
    return {
        "id": sample.image_id,
        "file_name": image_file_name(sample.image_id),
        "width": int(sample.rgb.shape[1]),
        "height": int(sample.rgb.shape[0]),
        "scene": sample.scene,
        "target_gate": None if sample.target < 0 else sample.target,
        "camera": {
            "K": _r(cam.K, 4),
            "hfov_deg": _r(cam.hfov_deg, 4),
            "uptilt_deg": _r(cam.uptilt_deg, 4),
            "roll_deg": _r(cam.roll_deg, 4),
            **lens,
        },
        "body_pos": _r(sample.pos, 4),
        "body_quat": _r(sample.quat, 6),
    }


PNG_PARAMS = (
    cv2.IMWRITE_PNG_FILTER, cv2.IMWRITE_PNG_FILTER_SUB,
    cv2.IMWRITE_PNG_STRATEGY, cv2.IMWRITE_PNG_STRATEGY_HUFFMAN_ONLY,
)  # fmt: skip
"""PNG settings: on these noisy renders as small as OpenCV's default and about 15% faster."""


def encode_png(rgb: np.ndarray) -> bytes:
    """PNG bytes of an (H, W, 3) uint8 RGB image."""
    ok, buf = cv2.imencode(".png", cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR), PNG_PARAMS)
    if not ok:  # pragma: no cover
        raise RuntimeError("PNG encoding failed")
    return buf.tobytes()


def _canonical(obj) -> bytes:
    return json.dumps(obj, sort_keys=True, separators=(",", ":"), allow_nan=False).encode()


def record_checksum(record: dict) -> str:
    """``sha256:<hex>`` of a shard record's content (everything but its ``checksum``)."""
    body = {k: v for k, v in record.items() if k != "checksum"}
    return "sha256:" + hashlib.sha256(_canonical(body)).hexdigest()


def render_shard(
    recipe: Recipe,
    seed: int,
    spec: ShardSpec,
    on_image: Callable[[str, bytes], None],
    renderer: str = "tiny",
) -> dict:
    """Render a shard: ``on_image(file_name, png)`` for each image in order; returns its record.

    The record is not written: :func:`write_shard` writes as it renders; a Ray task returns the
    images and the record to the process that writes them (``gen-dataset --ray``).
    """
    images, annotations = [], []
    for s in iter_samples(recipe, seed, spec, renderer):
        png = encode_png(s.rgb)
        on_image(image_file_name(s.image_id), png)
        images.append({**image_dict(s), "sha256": hashlib.sha256(png).hexdigest()})
        annotations += [annotation_dict(lab, s.image_id) for lab in s.labels]
    record = {
        "name": spec.name,
        "split": spec.split,
        "first_id": spec.first_id,
        "count": spec.count,
        "images": images,
        "annotations": annotations,
    }
    record["checksum"] = record_checksum(record)
    return record


def write_record(out_dir: Path, spec: ShardSpec, record: dict) -> dict:
    """Write a shard's record (after its images), atomically; returns it as a later run reads it."""
    data = json.dumps(record, separators=(",", ":"), allow_nan=False).encode()
    atomic_write_bytes(shard_path(Path(out_dir), spec), data)
    return json.loads(data)


def write_image(out_dir: Path, file_name: str, png: bytes) -> None:
    atomic_write_bytes(Path(out_dir) / IMAGES / file_name, png)


def write_shard(
    recipe: Recipe,
    seed: int,
    spec: ShardSpec,
    out_dir: Path,
    tick: Callable[[], None] | None = None,
    renderer: str = "tiny",
) -> dict:
    """Render a shard, write its PNGs and then its record, each atomically.

    Args:
        tick: called after each image is written (progress).
        renderer: ``"tiny"`` or ``"egl"``, as for :func:`iter_samples`.

    Returns:
        the shard record.
    """

    def on_image(name: str, png: bytes) -> None:
        write_image(out_dir, name, png)
        if tick is not None:
            tick()

    return write_record(out_dir, spec, render_shard(recipe, seed, spec, on_image, renderer))


def read_valid_shard(out_dir: Path, spec: ShardSpec) -> dict | None:
    """The shard's record if the shard is complete and intact, else None.

    Intact: the record parses, describes this shard, its checksum matches its content, and every
    image file exists with the recorded SHA-256.
    """
    out_dir = Path(out_dir)
    try:
        record = json.loads(shard_path(out_dir, spec).read_bytes())
        if not isinstance(record, dict) or record.get("checksum") != record_checksum(record):
            return None
        expect = (spec.name, spec.split, spec.first_id, spec.count)
        if (record["name"], record["split"], record["first_id"], record["count"]) != expect:
            return None
        images = record["images"]
        names = [(i, image_file_name(i)) for i in spec.image_ids]
        if [(im["id"], im["file_name"]) for im in images] != names:
            return None
        for im in images:
            data = (out_dir / IMAGES / im["file_name"]).read_bytes()
            if hashlib.sha256(data).hexdigest() != im["sha256"]:
                return None
    except (OSError, ValueError, KeyError, TypeError):
        return None
    return record
