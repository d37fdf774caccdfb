"""Loading a gen-dataset split (COCO keypoints + PNG) into memory, and the training ``Dataset``.

Images are resized once to the network input (INTER_AREA) when loaded; a 5,000-image split at
160x120 takes about 300 MB. Keypoints stay in camera pixels (u, v) until a sample is drawn.
Splits larger than memory can be kept in a ``.npy`` file mapped from disk (``disk``).
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from torch.utils.data import Dataset

from icarus_vision.dataset.importers import IMAGE_SUFFIXES
from icarus_vision.dataset.layout import SPLITS
from icarus_vision.fileio import atomic_path, atomic_write_json
from icarus_vision.gate_detect.base import FLIP_ORDER
from icarus_vision.gate_detect.cnn.augment import make_augment
from icarus_vision.gate_detect.cnn.model import letterbox_size, network_input


@dataclass(frozen=True)
class GateTruth:
    """One labelled gate.

    Attributes:
        corners: (4, 2) float64 camera pixels (u, v), TL, TR, BR, BL; NaN behind the camera.
        visibility: (4,) int COCO flags (2 visible, 1 hidden, 0 outside the image).
        distance: camera to gate centre, m.
        annotation: the COCO annotation it came from.
    """

    corners: np.ndarray
    visibility: np.ndarray
    distance: float
    annotation: dict


@dataclass
class Split:
    """One split of a dataset, loaded.

    Attributes:
        files: (N,) image paths.
        images: (N, h, w, 3) uint8 RGB at ``input_size`` (None when loaded without pixels).
        gates: per image, its labelled gates.
        image_info: per image, its COCO image entry (camera K, pose ...).
        image_size: (W, H) of the camera frames, pixels (of the first, where they differ).
        weights: per image, how often training draws it relative to the others (None: all
            alike); :func:`load_splits` gives each dataset its share.
    """

    files: list[Path]
    images: np.ndarray | None
    gates: list[list[GateTruth]]
    image_info: list[dict]
    image_size: tuple[int, int]
    weights: np.ndarray | None = None

    def size_of(self, i: int) -> tuple[int, int]:
        """(W, H) of image ``i`` (images of a COCO folder may differ in size)."""
        info = self.image_info[i]
        if "width" in info and "height" in info:
            return int(info["width"]), int(info["height"])
        return self.image_size


def read_rgb(path: Path) -> np.ndarray:
    """(H, W, 3) uint8 RGB of an image file.

    Raises:
        FileNotFoundError / ValueError: missing or unreadable, naming the file.
    """
    if not path.is_file():
        raise FileNotFoundError(f"{path}: image file not found")
    bgr = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if bgr is None:
        raise ValueError(f"{path}: cannot read the image (missing or corrupt)")
    return cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)


def _gate(a: dict) -> GateTruth:
    kp = np.asarray(a["keypoints"], float).reshape(4, 3)
    corners = np.array([c if c is not None else [np.nan, np.nan] for c in a["corners_px"]], float)
    return GateTruth(corners, kp[:, 2].astype(int), float(a.get("distance", np.nan)), a)


def load_split(
    data_dir: str | Path,
    split: str,
    input_size: tuple[int, int] | None = None,
    limit: int | None = None,
) -> Split:
    """Read ``annotations/<split>.json`` and its images.

    Args:
        data_dir: a gen-dataset output folder.
        split: ``train``, ``val`` or ``test``.
        input_size: (w, h) to resize the images to; None keeps them out of memory (labels only,
            though every image is still checked readable).
        limit: read only the first ``limit`` images.

    Raises:
        FileNotFoundError: no such folder or annotation file, or a missing image (named).
        ValueError: an unknown split, or an unreadable annotation file or image (named).
    """
    if split not in SPLITS:
        raise ValueError(f"split must be one of {', '.join(SPLITS)}, got {split!r}")
    root = Path(data_dir)
    if not root.is_dir():
        raise FileNotFoundError(f"{root}: dataset folder not found")
    ann_path = root / "annotations" / f"{split}.json"
    if not ann_path.is_file():
        raise FileNotFoundError(f"{ann_path}: annotation file not found (is {root} a dataset?)")
    try:
        coco = json.loads(ann_path.read_text())
        infos = sorted(coco["images"], key=lambda im: im["id"])[:limit]
        by_image: dict[int, list[GateTruth]] = {im["id"]: [] for im in infos}
        for a in coco["annotations"]:
            if a["image_id"] in by_image:
                by_image[a["image_id"]].append(_gate(a))
    except (ValueError, KeyError, TypeError, IndexError) as e:
        raise ValueError(f"{ann_path}: not a valid COCO keypoint file ({e})") from None
    if not infos:
        raise ValueError(f"{ann_path}: the {split} split holds no images")
    files = [root / "images" / im["file_name"] for im in infos]
    size = (int(infos[0]["width"]), int(infos[0]["height"]))
    return Split(files, _read_images(files, input_size), [by_image[im["id"]] for im in infos],
                 infos, size)  # fmt: skip


def load_eval_set(data_dir: str | Path, split: str = "test", limit: int | None = None) -> Split:
    """The labelled images ``eval-detector`` scores, from any of three kinds of folder:

    - a gen-dataset output folder (``annotations/<split>.json``): its ``split``, as
      :func:`load_split`;
    - a COCO-keypoints folder (``import-gates`` output, or any other): one ``.json`` file in the
      folder (or in its ``annotations/``), images in ``images/`` (or beside the file); keypoints
      TL, TR, BR, BL of category ``gate`` (an annotation of another category is ignored). No
      manifest, camera, distance or pose is needed; corners with visibility 0 are unknown;
    - a folder of images and nothing else: images without gates (every detection is a false
      positive).

    Images are not read (``images`` is None); every file is checked to exist.

    Raises:
        FileNotFoundError / ValueError: as :func:`load_split`, naming the file.
    """
    root = Path(data_dir)
    if not root.is_dir():
        raise FileNotFoundError(f"{root}: dataset folder not found")
    if (root / "annotations" / f"{split}.json").is_file():
        return load_split(root, split, None, limit)
    jsons = sorted(root.glob("*.json")) or sorted(root.glob("annotations/*.json"))
    jsons = [j for j in jsons if j.name not in ("config.json", "manifest.json")]
    if len(jsons) > 1:
        raise ValueError(
            f"{root}: {len(jsons)} JSON files ({', '.join(j.name for j in jsons[:3])}); a COCO "
            "folder holds one annotation file"
        )
    images_dir = root / "images" if (root / "images").is_dir() else root
    if not jsons:  # images without gates
        files = sorted(p for p in images_dir.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
        if not files:
            raise FileNotFoundError(f"{root}: no annotation file and no images found")
        files = files[:limit]
        return Split(files, None, [[] for _ in files], [{"file_name": f.name} for f in files],
                     (0, 0))  # fmt: skip
    return _coco_folder(jsons[0], images_dir if jsons[0].parent == root else root / "images",
                        limit)  # fmt: skip


def _coco_folder(ann_path: Path, images_dir: Path, limit: int | None) -> Split:
    try:
        coco = json.loads(ann_path.read_text())
        gate_ids = {c["id"] for c in coco.get("categories", []) if c.get("name") == "gate"}
        gate_ids = gate_ids or {c["id"] for c in coco.get("categories", [])}
        infos = sorted(coco["images"], key=lambda im: im["id"])[:limit]
        by_image: dict[int, list[GateTruth]] = {im["id"]: [] for im in infos}
        for a in coco["annotations"]:
            if a["image_id"] not in by_image or a.get("category_id", 1) not in gate_ids:
                continue
            kp = np.asarray(a["keypoints"], float).reshape(4, 3)
            corners = np.where(kp[:, 2:] > 0, kp[:, :2], np.nan)
            by_image[a["image_id"]].append(GateTruth(corners, kp[:, 2].astype(int), np.nan, a))
    except (ValueError, KeyError, TypeError, IndexError, AttributeError) as e:
        raise ValueError(f"{ann_path}: not a valid COCO keypoint file ({e})") from None
    if not infos:
        raise ValueError(f"{ann_path}: holds no images")
    files = [images_dir / im["file_name"] for im in infos]
    _read_images(files, None)
    size = (int(infos[0].get("width", 0)), int(infos[0].get("height", 0)))
    return Split(files, None, [by_image[im["id"]] for im in infos], infos, size)


def load_splits(
    data_dirs: list[str | Path],
    split: str,
    input_size: tuple[int, int] | None = None,
    limit: int | None = None,
    disk: Path | None = None,
    shares: list[float] | None = None,
    same_size: bool = True,
) -> Split:
    """:func:`load_split` of several datasets as one split. The images are read straight into
    one array: joining loaded splits would hold them twice. With ``disk`` (a ``.npy`` path),
    that array is a read-only file mapped from disk (:func:`mapped_images`), for splits larger
    than memory.

    Args:
        shares: each dataset's share of the training draws (``Split.weights``: a dataset of N
            images with share w gives each image w / N); None: every image alike.
        same_size: require one camera size, image by image (the refiner's patches assume
            it); the corner network letterboxes frames of any size, so its training mixes them
            (False). A COCO folder (real images from ``import-gates``, :func:`load_eval_set`)
            joins the ``train`` split whole; it has no other split (skipped without
            ``same_size``, else an error).

    Raises:
        ValueError: datasets of different image sizes where ``same_size``, or as
            :func:`load_split`.
    """
    parts, used = [], []
    for i, d in enumerate(data_dirs):
        coco = not (Path(d) / "annotations" / f"{split}.json").is_file()
        if coco and split == "train":
            part = load_eval_set(d, split, limit)
        elif coco and not same_size:
            continue  # a COCO folder has no val split
        else:
            part = load_split(d, split, None, limit)
        parts.append(part)
        used.append(i)
    if not parts:
        raise ValueError(f"none of {[str(d) for d in data_dirs]} has a {split} split")
    sizes = {s.size_of(i) for s in parts for i in range(len(s.files))}
    if same_size and len(sizes) != 1:
        raise ValueError(f"datasets of different image sizes cannot be combined: {sorted(sizes)}")
    files = [f for s in parts for f in s.files]
    images = (
        mapped_images(files, input_size, disk)
        if disk is not None and input_size is not None
        else _read_images(files, input_size)
    )
    weights = None
    if shares is not None:
        weights = np.concatenate(
            [
                np.full(len(s.files), shares[i] / len(s.files))
                for i, s in zip(used, parts, strict=True)
            ]
        )
    return Split(files, images, [g for s in parts for g in s.gates],
                 [i for s in parts for i in s.image_info], parts[0].image_size,
                 weights)  # fmt: skip


def _read_images(files: list[Path], input_size: tuple[int, int] | None) -> np.ndarray | None:
    """(N, h, w, 3) uint8 images at ``input_size``; None: only check that the files exist."""
    if input_size is None:
        for f in files:
            if not f.is_file():
                raise FileNotFoundError(f"{f}: image file not found")
        return None
    return _fill(np.empty((len(files), input_size[1], input_size[0], 3), np.uint8), files)


def _fill(images: np.ndarray, files: list[Path]) -> np.ndarray:
    """``images`` (N, h, w, 3) filled with the N image files, resized to (w, h)."""
    size = (images.shape[2], images.shape[1])
    for i, f in enumerate(files):
        images[i] = network_input(read_rgb(f), size)
    return images


def mapped_images(files: list[Path], input_size: tuple[int, int], path: Path) -> np.ndarray:
    """(N, h, w, 3) uint8 images at ``input_size``, read-only, mapped from the ``.npy`` file
    ``path``: written once (atomically; a JSON file beside it records which images, in which
    order, at which size and when they were modified), then reused while that record holds."""
    path = Path(path)
    record = path.with_suffix(".json")
    digest = hashlib.sha256()
    for f in files:  # load_split has checked that each exists
        digest.update(f"{f}\0{f.stat().st_mtime_ns}\0".encode())
    key = {"images": len(files), "size": list(input_size), "files": digest.hexdigest()}
    try:
        if path.is_file() and json.loads(record.read_text()) == key:
            return np.load(path, mmap_mode="r")
    except (OSError, ValueError):
        pass  # unreadable: write it again
    record.unlink(missing_ok=True)
    with atomic_path(path, suffix=".npy") as tmp:
        out = np.lib.format.open_memmap(
            tmp, mode="w+", dtype=np.uint8, shape=(len(files), input_size[1], input_size[0], 3)
        )
        _fill(out, files).flush()
        del out
    atomic_write_json(record, key)
    return np.load(path, mmap_mode="r")


class GateDataset(Dataset):
    """Augmented training samples: (image (3, h, w) float32 in [0, 1], target, weight).

    Args:
        split: a split loaded with images.
        grid: (w, h) of the network output, cells.
        augment: apply the training augmentation (else the image as is).
        seed: seed of the augmentation.
        ignore_below_px: gates whose opening's mean side is shorter than this (camera pixels)
            are no targets, and no peak near them is penalised (``encode_targets``).
    """

    def __init__(
        self,
        split: Split,
        grid: tuple[int, int],
        augment: bool,
        seed: int = 0,
        ignore_below_px: float = 0.0,
    ) -> None:
        from icarus_vision.gate_detect.cnn.targets import encode_targets

        self.split, self.grid, self.encode = split, grid, encode_targets
        self.ignore_below_px = ignore_below_px
        self.augment = make_augment(seed) if augment else None
        self.rng = np.random.default_rng(seed)

    def reseed(self, seed: int) -> None:
        """Restart the augmentation's random streams from ``seed``."""
        self.augment = make_augment(seed) if self.augment is not None else None
        self.rng = np.random.default_rng(seed)

    def __len__(self) -> int:
        return len(self.split.files)

    def __getitem__(self, i: int):
        img = self.split.images[i]
        h, w = img.shape[:2]
        pw, ph = letterbox_size(self.split.size_of(i), (w, h))  # frames are letterboxed
        sx, sy = w / pw, h / ph
        ignore_below = self.ignore_below_px * self.grid[0] / pw  # grid cells
        gates = self.split.gates[i]
        # (G, 4, 2) continuous input coordinates (left image edge at 0), NaN where unknown.
        kps = np.array([(g.corners + 0.5) * (sx, sy) for g in gates]).reshape(-1, 4, 2)
        vis = np.array([g.visibility for g in gates], int).reshape(-1, 4)
        if self.augment is not None:
            if self.rng.random() < 0.5:
                img, kps, vis = mirror(img, kps, vis)
            known = np.isfinite(kps).all(axis=2)
            flat = np.where(known[..., None], kps, -1e4).reshape(-1, 2)  # parked far away
            out = self.augment(image=np.ascontiguousarray(img), keypoints=flat)
            img = out["image"]
            kps = np.asarray(out["keypoints"], float).reshape(-1, 4, 2)
            kps = np.where(known[..., None], kps, np.nan)
            with np.errstate(invalid="ignore"):
                inside = (kps >= 0).all(axis=2) & (kps[..., 0] < w) & (kps[..., 1] < h)
            vis = np.where(inside, vis, 0)
        gx, gy = self.grid[0] / w, self.grid[1] / h
        items = [(k * (gx, gy), v) for k, v in zip(kps, vis, strict=True)]
        target, weight = self.encode(items, *self.grid, ignore_below=ignore_below)
        x = np.ascontiguousarray(img.transpose(2, 0, 1), dtype=np.float32) / 255.0
        return x, target, weight


def mirror(
    image: np.ndarray, kps: np.ndarray, vis: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Mirror an image left-right with its gates: TL <-> TR and BR <-> BL swap names.

    Args:
        image: (h, w, 3).
        kps: (G, 4, 2) continuous coordinates (left edge at x = 0), NaN allowed.
        vis: (G, 4) visibility flags.
    """
    w = image.shape[1]
    out = np.stack([w - kps[..., 0], kps[..., 1]], axis=-1)
    return image[:, ::-1], out[:, FLIP_ORDER], vis[:, FLIP_ORDER]
