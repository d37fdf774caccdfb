"""Saving and loading the corner network: ``model.safetensors`` + ``detector.json``, and ONNX.

A checkpoint is a folder holding the weights (safetensors: tensors only, nothing executable is
unpickled) and a JSON file with the architecture, the decoding thresholds and how it was trained.
A detector with a second stage also holds ``refiner.safetensors``, and its JSON a ``refine``
section (:class:`~icarus_vision.gate_detect.cnn.refine.RefineConfig`); one with a third stage
``zoom.safetensors`` and a ``zoom`` section
(:class:`~icarus_vision.gate_detect.cnn.zoom.ZoomConfig`). A quantized one (``quantize.py``) also
holds int8 ONNX copies of its networks (``model.int8.onnx``, ``refiner.int8.onnx``,
``zoom.int8.onnx``), and its JSON an ``int8`` section naming the float weights each was made from
(SHA-256). One with a fourth stage holds ``rescore.safetensors`` and a ``rescore`` section
(:class:`~icarus_vision.gate_detect.cnn.rescore.RescoreConfig`), added by :func:`save_rescorer`
to a saved checkpoint. Every file is written atomically.
``load_checkpoint`` accepts the folder or any of its files.
"""

from __future__ import annotations

import hashlib
import io
import json
import warnings
from dataclasses import asdict
from pathlib import Path

import torch
from safetensors import SafetensorError
from safetensors.torch import load_file, save_file

from icarus_vision.fileio import atomic_path, atomic_write_bytes, atomic_write_json
from icarus_vision.gate_detect.cnn.decode import DecodeConfig
from icarus_vision.gate_detect.cnn.model import CornerNet, ModelConfig
from icarus_vision.gate_detect.cnn.refine import RefineConfig, RefineNet
from icarus_vision.gate_detect.cnn.rescore import RescoreConfig, RescoreNet
from icarus_vision.gate_detect.cnn.zoom import ZoomConfig, ZoomNet

FORMAT = "icarus-vision-detector/1"
WEIGHTS, CONFIG, ONNX = "model.safetensors", "detector.json", "model.onnx"
REFINER, REFINER_ONNX = "refiner.safetensors", "refiner.onnx"
ZOOM = "zoom.safetensors"
RESCORE = "rescore.safetensors"
FLOAT_WEIGHTS = {"model": WEIGHTS, "refiner": REFINER, "zoom": ZOOM}
"""Each network's float weights file, by name."""
INT8 = {name: f"{name}.int8.onnx" for name in FLOAT_WEIGHTS}
"""Each network's int8 copy (``quantize.py``), by name."""
SHIPPED = Path(__file__).resolve().parents[2] / "models" / "detector"
"""The default detector shipped inside the package."""


def _save_weights(module: torch.nn.Module, path: Path) -> None:
    with atomic_path(path) as tmp:
        save_file({k: v.detach().contiguous() for k, v in module.state_dict().items()}, str(tmp))


def save_checkpoint(
    folder: str | Path,
    model: CornerNet,
    decode: DecodeConfig,
    info: dict | None = None,
    refiner: RefineNet | None = None,
    refine_info: dict | None = None,
    zoom: ZoomNet | None = None,
    zoom_info: dict | None = None,
) -> Path:
    """Write ``folder/model.safetensors`` and ``folder/detector.json`` (atomically), with a
    ``refiner`` (its config inside it) ``folder/refiner.safetensors`` and with a ``zoom`` stage
    ``folder/zoom.safetensors``; returns folder. Int8 copies there are deleted: they were made
    from other weights; so is a rescorer (it learnt other networks' outputs)."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    for name in (*INT8.values(), RESCORE):
        (folder / name).unlink(missing_ok=True)
    _save_weights(model, folder / WEIGHTS)
    meta = {"format": FORMAT, "model": model.cfg.to_dict(), "decode": asdict(decode)}
    if refiner is not None:
        _save_weights(refiner, folder / REFINER)
        meta["refine"] = refiner.cfg.to_dict()
    else:
        (folder / REFINER).unlink(missing_ok=True)
    if zoom is not None:
        _save_weights(zoom, folder / ZOOM)
        meta["zoom"] = zoom.cfg.to_dict()
    else:
        (folder / ZOOM).unlink(missing_ok=True)
    meta["training"] = info or {}
    if refine_info is not None:
        meta["refine_training"] = refine_info
    if zoom_info is not None:
        meta["zoom_training"] = zoom_info
    atomic_write_json(folder / CONFIG, meta)
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
    """The network (eval mode), its decoding thresholds and its JSON metadata (the refiner, if
    any: :func:`load_refiner`).

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
        if not isinstance(meta, dict):
            raise ValueError("expected a JSON object")
        if meta.get("format") != FORMAT:
            raise ValueError(f"format is {meta.get('format')!r}, expected {FORMAT!r}")
        model = CornerNet(ModelConfig.from_dict(meta["model"]))
        decode = DecodeConfig(**meta.get("decode", {}))
    except (ValueError, KeyError, TypeError, AttributeError) as e:
        raise ValueError(f"{cfg_path}: not a valid detector config ({e})") from None
    _load_weights(model, w_path, "detector")
    return model.eval(), decode, meta


def _load_weights(module: torch.nn.Module, path: Path, what: str) -> None:
    """Load safetensors weights into ``module`` (strict); a bad file is a ValueError naming it."""
    try:
        module.load_state_dict(load_file(str(path)), strict=True)
    except (SafetensorError, RuntimeError, OSError, ValueError) as e:
        msg = str(e).splitlines()[0] if str(e) else type(e).__name__
        raise ValueError(f"{path}: corrupt or incompatible {what} weights ({msg})") from None


def load_refiner(path: str | Path, meta: dict) -> RefineNet | None:
    """The second stage of the checkpoint at ``path`` (eval mode), None if it has none.

    Args:
        meta: the checkpoint's JSON metadata (from :func:`load_checkpoint`).

    Raises:
        FileNotFoundError / ValueError: a ``refine`` section without its weights, or corrupt
            weights or config (the file is named).
    """
    return _load_stage(path, meta, "refine", REFINER, "refiner", RefineNet, RefineConfig)


def load_zoom(path: str | Path, meta: dict) -> ZoomNet | None:
    """The zoom stage of the checkpoint at ``path`` (eval mode), None if it has none; as
    :func:`load_refiner` (its ``zoom`` section and ``zoom.safetensors``)."""
    return _load_stage(path, meta, "zoom", ZOOM, "zoom-stage", ZoomNet, ZoomConfig)


def load_rescorer(path: str | Path, meta: dict) -> RescoreNet | None:
    """The rescorer of the checkpoint at ``path`` (eval mode), None if it has none; as
    :func:`load_refiner` (its ``rescore`` section and ``rescore.safetensors``)."""
    return _load_stage(path, meta, "rescore", RESCORE, "rescorer", RescoreNet, RescoreConfig)


def save_rescorer(folder: str | Path, net: RescoreNet, record: dict) -> None:
    """Add a rescorer to the saved checkpoint at ``folder`` (its weights, then its config and
    ``record`` as the JSON's ``rescore`` and ``rescore_training`` sections, each atomically)."""
    folder = resolve(folder)
    meta = json.loads((folder / CONFIG).read_text())
    _save_weights(net, folder / RESCORE)
    meta["rescore"] = net.cfg.to_dict()
    meta["rescore_training"] = record
    atomic_write_json(folder / CONFIG, meta)


def _load_stage(path, meta: dict, key: str, weights: str, what: str, net_cls, cfg_cls):
    """A later stage's network from section ``key`` of ``meta`` and the file ``weights``."""
    if key not in meta:
        return None
    folder = resolve(path)
    w_path = folder / weights
    if not w_path.is_file():
        raise FileNotFoundError(f"{w_path}: {what} weights not found ({CONFIG} has a {what})")
    try:
        net = net_cls(cfg_cls.from_dict(meta[key]))
    except (ValueError, KeyError, TypeError) as e:
        raise ValueError(f"{folder / CONFIG}: not a valid {what} config ({e})") from None
    _load_weights(net, w_path, what)
    return net.eval()


def sha256(path: Path) -> str:
    """The SHA-256 of a file's bytes (hex)."""
    return hashlib.sha256(path.read_bytes()).hexdigest()


def save_int8(folder: str | Path, models: dict[str, bytes], record: dict) -> None:
    """Add int8 copies of the checkpoint's networks (ONNX ``models`` by name: ``model``,
    ``refiner``, ``zoom``) to the checkpoint at ``folder``: each file written atomically, then
    the ``int8`` section of its JSON (``record``, plus each file and its float weights'
    SHA-256), which makes them count."""
    folder = resolve(folder)
    meta = json.loads((folder / CONFIG).read_text())
    networks = {}
    for name, model in models.items():
        atomic_write_bytes(folder / INT8[name], model)
        networks[name] = {"file": INT8[name], "float_sha256": sha256(folder / FLOAT_WEIGHTS[name])}
    meta["int8"] = {**record, "networks": networks}
    atomic_write_json(folder / CONFIG, meta)


def int8_weight_bits(meta: dict) -> int | None:
    """Bits of the weights of a checkpoint's int8 copies, from its JSON ``meta`` (copies made
    before it recorded them have 8); None if it has no ``int8`` section. :func:`load_int8`
    checks the value."""
    return meta["int8"].get("weight_bits", 8) if "int8" in meta else None


def load_int8(path: str | Path, meta: dict) -> dict[str, bytes] | None:
    """The int8 ONNX copies of the checkpoint's networks, by name; None if it has none.

    Raises:
        FileNotFoundError: an ``int8`` section without its file (named).
        ValueError: a copy made from other weights than the checkpoint's, or not an ONNX model
            (the file is named), or a bad section.
    """
    if "int8" not in meta:
        return None
    import onnx

    folder = resolve(path)
    try:
        networks = meta["int8"]["networks"]
        entries = {name: (networks[name]["file"], networks[name]["float_sha256"])
                   for name in networks}  # fmt: skip
        if not set(entries) <= set(INT8):
            raise ValueError(f"unknown networks {sorted(set(entries) - set(INT8))}")
        bits = int8_weight_bits(meta)
        if type(bits) is not int or not 2 <= bits <= 8:
            raise ValueError(f"weight_bits must be an integer from 2 to 8, got {bits!r}")
    except (KeyError, TypeError, ValueError) as e:
        raise ValueError(f"{folder / CONFIG}: not a valid int8 section ({e})") from None
    models = {}
    for name, (file, digest) in entries.items():
        f = folder / file
        if not f.is_file():
            raise FileNotFoundError(f"{f}: int8 network not found ({CONFIG} has an int8 section)")
        if sha256(folder / FLOAT_WEIGHTS[name]) != digest:
            raise ValueError(
                f"{f}: made from other weights than {FLOAT_WEIGHTS[name]}; run "
                "icarus-vision quantize-detector again"
            )
        models[name] = f.read_bytes()
        try:
            onnx.load_model_from_string(models[name])
        except Exception as e:  # noqa: BLE001 - protobuf's decode errors
            raise ValueError(f"{f}: not an ONNX model ({type(e).__name__})") from None
    return models


def onnx_bytes(module: torch.nn.Module, inputs: tuple, **names) -> bytes:
    """``module`` (eval mode for the export) exported on example ``inputs`` to an ONNX model;
    ``names``: ``input_names``, ``output_names``, ``dynamic_axes``."""
    buf = io.BytesIO()
    was_training = module.training
    module.eval()
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            torch.onnx.export(module, inputs, buf, dynamo=False, opset_version=17, **names)
    finally:
        module.train(was_training)
    return buf.getvalue()


def _export(module: torch.nn.Module, inputs: tuple, path: str | Path, **names) -> Path:
    """:func:`onnx_bytes` written to ``path`` atomically."""
    atomic_write_bytes(path, onnx_bytes(module, inputs, **names))
    return Path(path)


def export_onnx(model: CornerNet, path: str | Path) -> Path:
    """Export the network (input ``image`` (1, 3, h, w) in [0, 1], output ``maps``) to ONNX."""
    w, h = model.cfg.input_size
    inputs = (torch.zeros(1, 3, h, w),)
    return _export(model, inputs, path, input_names=["image"], output_names=["maps"])


def export_refiner_onnx(net: RefineNet, path: str | Path) -> Path:
    """Export the refiner (inputs ``patches`` (N, 3, P, P) in [0, 1] and ``geometry`` (N, G),
    output ``refined`` (N, 9); N dynamic) to ONNX."""
    p = net.cfg.patch
    inputs = (torch.zeros(2, 3, p, p), torch.zeros(2, net.cfg.num_geom))
    return _export(
        net, inputs, path, input_names=["patches", "geometry"], output_names=["refined"],
        dynamic_axes={"patches": {0: "n"}, "geometry": {0: "n"}, "refined": {0: "n"}},
    )  # fmt: skip


def export_zoom_onnx(net: ZoomNet, path: str | Path) -> Path:
    """Export the zoom stage (input ``patches`` (N, 3, P, P) in [0, 1], output ``corners``
    (N, 2); N dynamic) to ONNX."""
    p = net.cfg.patch
    return _export(
        net, (torch.zeros(2, 3, p, p),), path, input_names=["patches"],
        output_names=["corners"], dynamic_axes={"patches": {0: "n"}, "corners": {0: "n"}},
    )  # fmt: skip
