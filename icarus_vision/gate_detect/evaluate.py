"""``eval_detector``: a detector's accuracy and speed on a dataset's test split, and its error model.

The matching rule and which gates count are in :mod:`icarus_vision.gate_detect.metrics`. Inference
time is measured per frame around ``Detector.detect`` (resizing and decoding included, file reading
excluded), with PyTorch and OpenCV limited to one thread.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from contextlib import contextmanager
from pathlib import Path

import cv2
import numpy as np

from icarus_vision.fileio import atomic_write_bytes, atomic_write_json
from icarus_vision.gate_detect.cnn import cpu_description
from icarus_vision.gate_detect.cnn.data import load_eval_set, read_rgb
from icarus_vision.gate_detect.draw import draw_detections, sheet
from icarus_vision.gate_detect.error_model import build_error_model, gate_error, viewing_angle_deg
from icarus_vision.gate_detect.metrics import (
    DISTANCE_BINS_M,
    SIZE_BINS_PX,
    binned,
    confidence,
    evaluable,
    evaluate_image,
    summarize,
)
from icarus_vision.gate_detect.registry import make_detector

GATE_SIZE_M = 1.0
"""Opening side assumed to estimate the distance of a false positive from its apparent size."""


@contextmanager
def one_thread():
    """Limit PyTorch and OpenCV to one thread for the duration (restored afterwards)."""
    import torch

    torch_n, cv_n = torch.get_num_threads(), cv2.getNumThreads()
    torch.set_num_threads(1)
    cv2.setNumThreads(1)
    try:
        yield
    finally:
        torch.set_num_threads(torch_n)
        cv2.setNumThreads(cv_n)


def eval_detector(
    data_dir: str | Path,
    detector_spec: str,
    json_path: str | Path | None = None,
    error_model_path: str | Path | None = None,
    min_gate_px: float = 20.0,
    split: str = "test",
    limit: int | None = None,
    progress: Callable[[int, int], None] | None = None,
    examples_path: str | Path | None = None,
    examples: int = 12,
    seed: int = 0,
    resamples: int = 1000,
    backend: str | None = None,
    min_score: float | None = None,
) -> dict:
    """Evaluate a detector on a gen-dataset split, a COCO-keypoints folder (e.g. real images
    from ``import-gates``; breakdowns by apparent size only, no error model) or a folder of
    images without gates (:func:`~icarus_vision.gate_detect.cnn.data.load_eval_set`).

    Args:
        data_dir: gen-dataset output folder, COCO-keypoints folder or folder of images.
        detector_spec: ``cnn``, ``cnn:PATH`` or ``opencv``.
        json_path: also write the report here.
        error_model_path: write the error model here (default: beside ``json_path`` as
            ``<stem>.error_model.json``; not written when both are None).
        min_gate_px: smallest counted gate (mean side of the opening), pixels.
        split: which split.
        limit: evaluate only the first ``limit`` images.
        progress: called with (images done, total).
        examples_path: also write a picture (JPEG or PNG, by suffix) of ``examples`` images spread
            evenly over the split, with the true (green) and detected (cyan, TL dotted) openings.
        examples: how many images that picture shows.
        seed: seed of the bootstrap (``confidence``).
        resamples: bootstrap resamples of the test images (0: no ``confidence``).
        backend: what runs a CNN's networks (``CnnDetector``'s ``backend``: auto, int8,
            onnxruntime or torch); None: its default, auto. Only for a ``cnn`` spec.
        min_score: count only the gates the detector scores at least this (``CnnDetector``'s
            ``min_score``; None: all it reports). Only for a ``cnn`` spec.

    Returns:
        the report: detector, backend (a CNN's: what ran its networks), min_score, images, gates, min_gate_px, precision, recall, corner_error_px
        {mean, median}, pck {2px, 5px}, confidence (95 % bootstrap intervals of those figures
        over the test images: :func:`~icarus_vision.gate_detect.metrics.confidence`),
        ms_per_frame (and its median, and the ``cpu`` it ran on), by_distance, by_size,
        matching_rule, error_model (the model itself) and
        error_model_path.

    Raises:
        FileNotFoundError / ValueError: bad dataset (naming the first bad file) or detector spec.
    """
    if min_gate_px < 0:
        raise ValueError(f"min_gate_px must be >= 0, got {min_gate_px}")
    if resamples < 0:
        raise ValueError(f"resamples must be >= 0, got {resamples}")
    ext = (Path(examples_path).suffix.lower() or ".jpg") if examples_path is not None else None
    if ext is not None and not cv2.haveImageWriter(f"examples{ext}"):
        raise ValueError(f"{examples_path}: cannot write an image of this type (use .jpg or .png)")
    settings = {k: v for k, v in (("backend", backend), ("min_score", min_score)) if v is not None}
    detector = make_detector(detector_spec, **settings)
    data = load_eval_set(data_dir, split, limit)
    gts, preds, samples, times, tiles, per_image = [], [], [], [], [], []
    n = len(data.files)
    shown = set(np.linspace(0, n - 1, min(examples, n)).round().astype(int).tolist())
    with one_thread():
        for i, path in enumerate(data.files):
            image = read_rgb(path)
            t0 = time.perf_counter()
            found = detector.detect(image)
            times.append(time.perf_counter() - t0)
            camera = data.image_info[i].get("camera")
            k = None if camera is None else np.asarray(camera["K"], float)
            truth = [(g.corners, g.visibility, g.distance) for g in data.gates[i]]
            g_rec, p_rec = evaluate_image([(d.corners, d.score) for d in found], truth, min_gate_px)
            for p in p_rec:
                if p["distance"] is None and p["side"] > 0 and k is not None:
                    p["distance"] = k[0, 0] * GATE_SIZE_M / p["side"]
            for g, gate in zip(g_rec, data.gates[i], strict=True):
                if evaluable(gate.corners, gate.visibility) and np.isfinite(gate.distance):
                    samples.append(_sample(g, gate, k))
            gts += g_rec
            preds += p_rec
            per_image.append((g_rec, p_rec))
            if examples_path is not None and i in shown:
                tiles.append(draw_detections(image, found, [t[0] for t in truth]))
            if progress is not None:
                progress(i + 1, n)
    report = {
        "detector": detector_spec,
        "backend": getattr(detector, "backend", None),
        "min_score": getattr(detector, "min_score", None),
        "split": split,
        "data": str(data_dir),
        "images": n,
        "has_distance": bool(any(np.isfinite(g.distance) for gs in data.gates for g in gs)),
        "min_gate_px": min_gate_px,
        **summarize(gts, preds, min_gate_px),
        "confidence": (
            confidence(per_image, min_gate_px, resamples, seed=seed) if resamples else None
        ),
        "ms_per_frame": round(1000.0 * float(np.mean(times[1:] or times)), 3),
        "ms_per_frame_median": round(1000.0 * float(np.median(times)), 3),
        "cpu": cpu_description(),
        "by_distance": binned(gts, preds, "distance", DISTANCE_BINS_M, min_gate_px),
        "by_size": binned(gts, preds, "side", SIZE_BINS_PX, 0.0),
        "matching_rule": (
            "greedy by score; a detection matches the unmatched true gate with the smallest mean "
            "corner distance if <= max(4 px, 0.25 x its mean side); counted gates: 4 corners in "
            "the image, >= 3 visible, mean side >= min_gate_px"
        ),
    }
    model = build_error_model(samples, detector_spec) if samples else None
    if error_model_path is None and json_path is not None:
        error_model_path = Path(json_path).with_suffix(".error_model.json")
    if model is not None and error_model_path is not None:
        atomic_write_json(error_model_path, model)
    report["error_model_path"] = str(error_model_path) if model and error_model_path else None
    report["error_model"] = model
    report["examples_path"] = None
    if examples_path is not None and tiles:
        params = [cv2.IMWRITE_JPEG_QUALITY, 85] if ext in (".jpg", ".jpeg") else []
        ok, encoded = cv2.imencode(ext, cv2.cvtColor(sheet(tiles), cv2.COLOR_RGB2BGR), params)
        if not ok:
            raise ValueError(
                f"{examples_path}: cannot write an image of this type (use .jpg or .png)"
            )
        atomic_write_bytes(examples_path, encoded.tobytes())
        report["examples_path"] = str(examples_path)
    if json_path is not None:
        atomic_write_json(json_path, report)
    return report


def _sample(rec: dict, gate, k: np.ndarray) -> dict:
    pose = gate.annotation.get("gate_pose") or {}
    angle = np.nan
    if pose.get("R_cam_gate") is not None and pose.get("t_cam_gate") is not None:
        angle = viewing_angle_deg(pose["R_cam_gate"], pose["t_cam_gate"])
    error = None
    if rec["matched"]:
        error = gate_error(rec["pred_corners"], gate.corners, k, gate.distance)
    return {
        "distance": gate.distance,
        "angle_deg": angle,
        "matched": rec["matched"],
        "error": error,
        "corner_px": rec["errors"],
    }
