"""Saving and loading the corner network: ``model.safetensors`` + ``detector.json``, and ONNX.

A checkpoint is a folder holding the weights (safetensors: tensors only, nothing executable is
unpickled) and a JSON file with the architecture, the decoding thresholds and how it was trained.
Every file is written atomically. ``load_checkpoint`` accepts the folder or either file.
"""

from __future__ import annotations

import json
import os
import warnings
from dataclasses import asdict
from pathlib import Path

import torch
from safetensors import SafetensorError
from safetensors.torch import load_file, save_file

from icarus_vision.fileio import atomic_write_json
from icarus_vision.gate_detect.cnn.decode import DecodeConfig
from icarus_vision.gate_detect.cnn.model import CornerNet, ModelConfig

FORMAT = "icarus-vision-detector/1"
WEIGHTS, CONFIG, ONNX = "model.safetensors", "detector.json", "model.onnx"
SHIPPED = Path(__file__).resolve().parents[2] / "models" / "detector"
"""The default detector shipped inside the package."""


def save_checkpoint(
    folder: str | Path, model: CornerNet, decode: DecodeConfig, info: dict | None = None
) -> Path:
    """Write ``folder/model.safetensors`` and ``folder/detector.json`` (atomically); returns folder."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    tmp = folder / f".{WEIGHTS}.tmp"
    state = {k: v.detach().contiguous() for k, v in model.state_dict().items()}
    save_file(state, str(tmp))
    os.replace(tmp, folder / WEIGHTS)
    meta = {"format": FORMAT, "model": model.cfg.to_dict(), "decode": asdict(decode)}
    atomic_write_json(folder / CONFIG, {**meta, "training": info or {}})
    return folder


def resolve(path: str | Path) -> Path:
    """The checkpoint folder of ``path`` (the folder itself or one of its two files)."""
    p = Path(path)
    if p.is_file():
        return p.parent
    if not p.exists():
        raise FileNotFoundError(f"{p}: detector checkpoint not found")
    return p


def load_checkpoint(path: str | Path) -> tuple[CornerNet, DecodeConfig, dict]:
    """The network (eval mode), its decoding thresholds and its JSON metadata.

    Raises:
        FileNotFoundError: no checkpoint there (the missing file is named).
        ValueError: a corrupt or incompatible checkpoint (the file is named).
    """
    folder = resolve(path)
    cfg_path, w_path = folder / CONFIG, folder / WEIGHTS
    for f in (cfg_path, w_path):
        if not f.is_file():
            raise FileNotFoundError(f"{f}: detector checkpoint file not found")
    try:
        meta = json.loads(cfg_path.read_text())
        if meta.get("format") != FORMAT:
            raise ValueError(f"format is {meta.get('format')!r}, expected {FORMAT!r}")
        model = CornerNet(ModelConfig.from_dict(meta["model"]))
        decode = DecodeConfig(**meta.get("decode", {}))
    except (ValueError, KeyError, TypeError) as e:
        raise ValueError(f"{cfg_path}: not a valid detector config ({e})") from None
    try:
        state = load_file(str(w_path))
        model.load_state_dict(state, strict=True)
    except (SafetensorError, RuntimeError, OSError, ValueError) as e:
        msg = str(e).splitlines()[0] if str(e) else type(e).__name__
        raise ValueError(f"{w_path}: corrupt or incompatible detector weights ({msg})") from None
    return model.eval(), decode, meta


def export_onnx(model: CornerNet, path: str | Path) -> Path:
    """Export the network (input ``image`` (1, 3, h, w) in [0, 1], output ``maps``) to ONNX."""
    path = Path(path)
    w, h = model.cfg.input_size
    tmp = path.with_name(f".{path.name}.tmp")
    was_training = model.training
    model.eval()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        torch.onnx.export(
            model,
            (torch.zeros(1, 3, h, w),),
            str(tmp),
            dynamo=False,
            input_names=["image"],
            output_names=["maps"],
            opset_version=17,
        )
    os.replace(tmp, path)
    model.train(was_training)
    return path
