"""A contact sheet: a grid of generated images with their labelled corners drawn, for a person."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from icarus_vision.dataset.layout import IMAGES
from icarus_vision.render.labels import HIDDEN, VISIBLE

# BGR colours: opening outline, visible corner, hidden corner, text.
_EDGE, _VIS, _HID, _TEXT = (60, 255, 60), (0, 255, 0), (0, 220, 255), (255, 255, 255)


def pick_images(images: list[dict], n: int) -> list[dict]:
    """Up to ``n`` image entries spread evenly over the list (first and last included)."""
    if len(images) <= n:
        return list(images)
    idx = np.unique(np.round(np.linspace(0, len(images) - 1, n)).astype(int))
    return [images[i] for i in idx]


def draw_labels(img: np.ndarray, anns: list[dict], scale: float = 1.0) -> None:
    """Draw each gate's opening (TL-TR-BR-BL, from ``corners_px``) and its corner flags, in place.

    Args:
        img: (H, W, 3) uint8 BGR image (already resized by ``scale``).
        anns: COCO annotations of the image (see :mod:`icarus_vision.dataset.coco`).
        scale: image size / labelled size.
    """
    sh = 4  # fixed-point bits for sub-pixel drawing
    for a in anns:
        pts = [p for p in a["corners_px"] if p is not None]
        if len(pts) == 4:
            poly = np.round(np.array(pts) * scale * (1 << sh)).astype(np.int32)
            cv2.polylines(img, [poly], True, _EDGE, 1, cv2.LINE_AA, shift=sh)
        x0, y0, bw = (v * scale for v in a["bbox"][:3])
        radius = int(round(min(3.0, max(1.0, bw / 10.0)) * (1 << sh)))
        for x, y, v in np.asarray(a["keypoints"], dtype=float).reshape(4, 3):
            if v in (VISIBLE, HIDDEN):
                c = (int(round(x * scale * (1 << sh))), int(round(y * scale * (1 << sh))))
                color = _VIS if v == VISIBLE else _HID
                cv2.circle(img, c, radius, color, -1 if v == VISIBLE else 1, cv2.LINE_AA, sh)
        if bw >= 20:  # name the distance of the larger gates only, to keep the tile readable
            org = (int(max(x0, 0)), int(max(y0 - 3, 10)))
            cv2.putText(img, f"{a['distance']:.1f}m", org, cv2.FONT_HERSHEY_PLAIN, 0.8, _TEXT, 1)


def contact_sheet(
    out_dir: Path, images: list[dict], anns: list[dict], n: int = 16, cols: int = 4
) -> bytes:
    """PNG bytes of a grid of up to ``n`` images of ``out_dir/images`` with their labels.

    Args:
        out_dir: the dataset folder.
        images: COCO image entries to choose from (in id order).
        anns: COCO annotations of those images.
        n: number of tiles; cols: tiles per row. Tiles are at most 320 pixels wide.
    """
    chosen = pick_images(images, n)
    if not chosen:
        return cv2.imencode(".png", np.zeros((8, 8, 3), np.uint8))[1].tobytes()
    by_image: dict[int, list[dict]] = {}
    for a in anns:
        by_image.setdefault(a["image_id"], []).append(a)
    w0, h0 = chosen[0]["width"], chosen[0]["height"]
    scale = min(1.0, 320.0 / w0)
    tw, th = int(round(w0 * scale)), int(round(h0 * scale))
    cols = min(cols, len(chosen))
    rows = -(-len(chosen) // cols)
    sheet = np.full((rows * th, cols * tw, 3), 32, np.uint8)
    for i, im in enumerate(chosen):
        tile = cv2.imread(str(Path(out_dir) / IMAGES / im["file_name"]), cv2.IMREAD_COLOR)
        if tile is None:
            raise RuntimeError(f"{out_dir}: cannot read {im['file_name']} for the contact sheet")
        if scale != 1.0:
            tile = cv2.resize(tile, (tw, th), interpolation=cv2.INTER_AREA)
        draw_labels(tile, by_image.get(im["id"], []), scale)
        cv2.putText(tile, f"#{im['id']}", (3, th - 5), cv2.FONT_HERSHEY_PLAIN, 0.9, _TEXT, 1)
        r, c = divmod(i, cols)
        sheet[r * th : (r + 1) * th, c * tw : (c + 1) * tw] = tile
    return cv2.imencode(".png", sheet)[1].tobytes()
