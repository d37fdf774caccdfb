"""Labelled gate images from the formats public sets use, written as a COCO-keypoints folder.

``import-gates`` reads one of:

- ``alphapilot``: the AlphaPilot (AIRR 2019) JSON, ``{"IMG_0005.JPG": [[x1, y1, ..., x4, y4], ...]}``,
  one list of eight pixel coordinates per gate (an empty list or ``[[]]``: no gate);
- ``corners-csv``: a CSV of ``filename,x1,y1,x2,y2,x3,y3,x4,y4``, one row per gate (a header row
  is skipped);
- ``yolo-pose``: one label file per image (``labels/<stem>.txt``), a line per gate of
  ``cls cx cy w h x1 y1 v1 ... x4 y4 v4`` (or without the ``v``), normalised to the image's size
  (the TII "Race Against the Machine" layout: ``images/`` and ``labels/`` side by side).

and writes ``OUT/images/`` (the image files, copied) and ``OUT/annotations.json`` (COCO keypoints,
one ``gate`` category, corners TL, TR, BR, BL: :mod:`icarus_vision.dataset.coco`). Public sets do not
agree on which corner comes first, so every gate's corners are put in the order they are seen in
the image (:func:`order_as_seen`). ``eval-detector --data OUT`` reads the result.
"""

from __future__ import annotations

import csv
import json
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np

from icarus_vision.dataset.coco import CATEGORY
from icarus_vision.fileio import atomic_write_bytes, atomic_write_json
from icarus_vision.render.labels import OUTSIDE, VISIBLE

FORMATS = ("alphapilot", "corners-csv", "yolo-pose")
"""Formats ``import-gates`` reads."""
IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png", ".bmp", ".tif", ".tiff", ".webp")
"""Image files an imported folder may hold (case-insensitive)."""
ANNOTATIONS = "annotations.json"
"""The imported folder's annotation file."""

Labels = dict[str, list[np.ndarray]]
"""Per image file name: its gates, (4, 3) arrays of x, y, COCO visibility each."""


def order_as_seen(corners: np.ndarray) -> np.ndarray:
    """(4, 2) corners of one opening in TL, TR, BR, BL order as seen in the image (y down).

    The corners are sorted clockwise around their centroid, and the cyclic start is the one
    whose directions from the centroid are nearest to up-left, up-right, down-right, down-left
    (so a gate rolled by less than 45 degrees keeps its top-left corner first).
    """
    q = np.asarray(corners, float)
    d = q - q.mean(axis=0)
    angle = np.arctan2(d[:, 1], d[:, 0])  # clockwise on screen, as y points down
    q, angle = q[np.argsort(angle, kind="stable")], np.sort(angle)
    ideal = np.radians([-135.0, -45.0, 45.0, 135.0])
    cost = [np.abs(np.angle(np.exp(1j * (np.roll(angle, -s) - ideal)))).sum() for s in range(4)]
    return np.roll(q, -int(np.argmin(cost)), axis=0)


def _gate(values: list[float], where: str) -> np.ndarray:
    """(4, 3) x, y, visibility of eight pixel coordinates, in the order seen."""
    if len(values) != 8:
        raise ValueError(f"{where}: a gate needs 8 numbers (x1, y1 ... x4, y4), got {len(values)}")
    xy = np.asarray(values, float).reshape(4, 2)
    if not np.isfinite(xy).all():
        raise ValueError(f"{where}: corner coordinates must be finite numbers")
    return np.column_stack((order_as_seen(xy), np.full(4, VISIBLE)))


def read_alphapilot(path: Path) -> Labels:
    """Gates of an AlphaPilot label file (module docstring)."""
    try:
        raw = json.loads(path.read_text())
    except (OSError, ValueError) as e:
        raise ValueError(f"{path}: not a readable JSON file ({e})") from None
    if not isinstance(raw, dict):
        raise ValueError(f"{path}: expected an object of image name -> list of gates")
    out: Labels = {}
    for name, gates in raw.items():
        if not isinstance(gates, list) or not all(isinstance(g, list) for g in gates):
            raise ValueError(f"{path}: {name}: expected a list of [x1, y1, ..., x4, y4] lists")
        try:
            out[name] = [_gate([float(v) for v in g], f"{path}: {name}") for g in gates if g]
        except (TypeError, ValueError) as e:
            msg = str(e) if str(e).startswith(str(path)) else f"{path}: {name}: {e}"
            raise ValueError(msg) from None
    return out


def read_corners_csv(path: Path) -> Labels:
    """Gates of a ``filename,x1,y1,...,x4,y4`` CSV (module docstring)."""
    out: Labels = {}
    try:
        rows = list(csv.reader(path.read_text().splitlines()))
    except (OSError, UnicodeDecodeError, csv.Error) as e:
        raise ValueError(f"{path}: not a readable CSV file ({e})") from None
    for n, row in enumerate(rows, 1):
        cells = [c.strip() for c in row]
        if not any(cells):
            continue
        where = f"{path}, line {n}"
        if len(cells) != 9:
            raise ValueError(
                f"{where}: expected filename and 8 coordinates, got {len(cells)} cells"
            )
        try:
            values = [float(c) for c in cells[1:]]
        except ValueError:
            if n == 1:  # a header
                continue
            raise ValueError(f"{where}: coordinates must be numbers, got {cells[1:]}") from None
        out.setdefault(cells[0], []).append(_gate(values, where))
    return out


def read_yolo_pose(labels_dir: Path, sizes: dict[str, tuple[int, int]]) -> Labels:
    """Gates of a folder of YOLO-pose label files, for the images in ``sizes`` (name -> (w, h)):
    ``labels/<stem>.txt`` per image (module docstring); an image without a label file has no
    gate. Keypoints with visibility 0 are kept as outside the image."""
    out: Labels = {}
    for name, (w, h) in sizes.items():
        txt = labels_dir / (Path(name).stem + ".txt")
        out[name] = []
        if not txt.is_file():
            continue
        for n, line in enumerate(txt.read_text().splitlines(), 1):
            if not line.strip():
                continue
            where = f"{txt}, line {n}"
            try:
                v = [float(x) for x in line.split()]
            except ValueError:
                raise ValueError(f"{where}: expected numbers, got {line.strip()!r}") from None
            if len(v) not in (5 + 8, 5 + 12):
                raise ValueError(
                    f"{where}: expected cls cx cy w h and 4 keypoints (x y or x y v), "
                    f"got {len(v)} numbers"
                )
            kp = np.asarray(v[5:], float).reshape(4, -1)
            vis = kp[:, 2] if kp.shape[1] == 3 else np.full(4, VISIBLE)
            xy = kp[:, :2] * (w, h)
            if not np.isfinite(kp).all():
                raise ValueError(f"{where}: keypoints must be finite numbers")
            if (vis == 0).any():  # unlabelled corners: keep the order given, mark them outside
                out[name].append(np.column_stack((xy, np.where(vis > 0, VISIBLE, OUTSIDE))))
            else:
                out[name].append(np.column_stack((order_as_seen(xy), np.full(4, VISIBLE))))
    return out


def _images(folder: Path) -> dict[str, Path]:
    if not folder.is_dir():
        raise FileNotFoundError(f"{folder}: image folder not found (pass --images)")
    return {p.name: p for p in sorted(folder.iterdir()) if p.suffix.lower() in IMAGE_SUFFIXES}


def _size(path: Path) -> tuple[int, int]:
    image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if image is None:
        raise ValueError(f"{path}: cannot read the image (missing or corrupt)")
    return int(image.shape[1]), int(image.shape[0])


def label_source(fmt: str, src: Path) -> Path:
    """The label file (or, for yolo-pose, folder) in ``src``: ``src`` itself when it is one,
    else the one JSON / CSV file or the ``labels/`` folder inside it."""
    if fmt not in FORMATS:
        raise ValueError(f"format must be one of {', '.join(FORMATS)}, got {fmt!r}")
    if not src.exists():
        raise FileNotFoundError(f"{src}: not found")
    if fmt == "yolo-pose":
        folder = src / "labels" if (src / "labels").is_dir() else src
        if not any(folder.glob("*.txt")):
            raise FileNotFoundError(f"{src}: no YOLO label files (labels/*.txt) found")
        return folder
    if src.is_file():
        return src
    suffix = ".json" if fmt == "alphapilot" else ".csv"
    found = sorted(p for p in src.iterdir() if p.suffix.lower() == suffix)
    if len(found) != 1:
        raise FileNotFoundError(
            f"{src}: expected one {suffix} label file, found {len(found)}; pass the file itself"
        )
    return found[0]


def import_gates(
    fmt: str,
    src: str | Path,
    out: str | Path,
    images: str | Path | None = None,
    unlabelled: bool = False,
    progress: Callable[[int, int], None] | None = None,
) -> dict:
    """Convert a labelled gate set to a COCO-keypoints folder (module docstring).

    Args:
        fmt: one of :data:`FORMATS`.
        src: the label file or folder, or a folder holding it (and ``images/``).
        out: the folder to write; it must be empty or absent.
        images: the image folder (default: ``images/`` beside the labels, else the labels' folder).
        unlabelled: also import the images that have no label entry, as images without gates
            (for yolo-pose an image without a label file is always one).
        progress: called with (images done, total).

    Returns:
        a summary: format, images, gates, images_without_gates, out.

    Raises:
        FileNotFoundError / ValueError: missing or malformed input, naming the file and entry;
            a label for an image that is not there; a non-empty ``out``.
    """
    src, out = Path(src), Path(out)
    labels_at = label_source(fmt, src)
    if images is None:
        base = src if src.is_dir() else src.parent
        images = base / "images" if (base / "images").is_dir() else base
        if fmt == "yolo-pose" and labels_at.name == "labels":
            images = labels_at.parent / "images"
    files = _images(Path(images))
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        raise ValueError(f"{out}: exists and is not an empty folder; choose another --out")
    sizes: dict[str, tuple[int, int]] = {}
    if fmt == "yolo-pose":
        sizes = {n: _size(p) for n, p in files.items()}
        labels = read_yolo_pose(labels_at, sizes)
    else:
        labels = (read_alphapilot if fmt == "alphapilot" else read_corners_csv)(labels_at)
        missing = sorted(set(labels) - set(files))
        if missing:
            raise FileNotFoundError(
                f"{labels_at}: {len(missing)} labelled image(s) not in {images} "
                f"(first: {missing[0]}); pass --images"
            )
        if unlabelled:
            labels |= {n: [] for n in files if n not in labels}
    names = sorted(labels)
    coco_images, anns = [], []
    (out / "images").mkdir(parents=True, exist_ok=True)
    for i, name in enumerate(names, 1):
        path = files[name]
        w, h = sizes[name] if name in sizes else _size(path)
        coco_images.append({"id": i, "file_name": name, "width": w, "height": h})
        for gate in labels[name]:
            anns.append(_annotation(len(anns) + 1, i, gate))
        atomic_write_bytes(out / "images" / name, path.read_bytes())
        if progress is not None:
            progress(i, len(names))
    coco = {
        "info": {"description": f"gates imported from {labels_at} ({fmt})", "format": fmt},
        "licenses": [],
        "images": coco_images,
        "annotations": anns,
        "categories": [CATEGORY],
    }
    atomic_write_json(out / ANNOTATIONS, coco)
    with_gates = {a["image_id"] for a in anns}
    return {
        "format": fmt,
        "images": len(coco_images),
        "gates": len(anns),
        "images_without_gates": len(coco_images) - len(with_gates),
        "out": str(out),
    }


def _annotation(ann_id: int, image_id: int, gate: np.ndarray) -> dict:
    xy, vis = gate[:, :2], gate[:, 2].astype(int)
    seen = xy[vis > 0]
    x0, y0 = seen.min(axis=0) if len(seen) else (0.0, 0.0)
    x1, y1 = seen.max(axis=0) if len(seen) else (0.0, 0.0)
    keypoints = []
    for (x, y), v in zip(xy, vis, strict=True):
        keypoints += [round(float(x), 3), round(float(y), 3), int(v)] if v else [0, 0, 0]
    return {
        "id": ann_id,
        "image_id": image_id,
        "category_id": CATEGORY["id"],
        "keypoints": keypoints,
        "num_keypoints": int((vis > 0).sum()),
        "bbox": [round(float(v), 3) for v in (x0, y0, x1 - x0, y1 - y0)],
        "area": round(float((x1 - x0) * (y1 - y0)), 3),
        "iscrowd": 0,
    }


__all__ = ["ANNOTATIONS", "FORMATS", "import_gates", "order_as_seen", "read_alphapilot",
           "read_corners_csv", "read_yolo_pose"]  # fmt: skip
