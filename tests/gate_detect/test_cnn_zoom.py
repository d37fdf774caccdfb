"""The detector's third stage: zoomed corner patches, moved corners, training, checkpoints."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest
import torch

from icarus_vision.gate_detect import make_detector
from icarus_vision.gate_detect.cnn import CnnDetector, OnnxRuntimeNet
from icarus_vision.gate_detect.cnn import zoom_train as zt
from icarus_vision.gate_detect.cnn.checkpoint import (
    export_zoom_onnx,
    load_checkpoint,
    load_zoom,
    save_checkpoint,
)
from icarus_vision.gate_detect.cnn.data import load_split
from icarus_vision.gate_detect.cnn.decode import DecodeConfig
from icarus_vision.gate_detect.cnn.model import CornerNet
from icarus_vision.gate_detect.cnn.rectify import extract, transform
from icarus_vision.gate_detect.cnn.refine import RefineConfig, RefineNet
from icarus_vision.gate_detect.cnn.zoom import (
    ZoomConfig,
    ZoomNet,
    homographies,
    mirror_mean,
    rolled,
    sharpen,
    square,
    to_corners,
    to_targets,
)

from .conftest import QUAD, TINY_MODEL, facing_box, gate_image

CFG = ZoomConfig(patch=24, widths=(4, 8, 8, 8), hidden=16)


def _zoom(seed: int = 0, cfg: ZoomConfig = CFG) -> ZoomNet:
    torch.manual_seed(seed)
    return ZoomNet(cfg).eval()


class Fixed(torch.nn.Module):
    """A stand-in zoom network that always answers ``out``."""

    def __init__(self, out) -> None:
        super().__init__()
        self.out = torch.tensor(out, dtype=torch.float32)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.out.expand(len(x), 2)


def test_each_corner_lands_at_its_patch_centre_with_the_next_one_to_the_right():
    h, back = homographies(QUAD[None], CFG)
    assert h.shape == back.shape == (4, 3, 3)
    c = CFG.patch / 2 - 0.5
    for i in range(4):
        moved = transform(h[i : i + 1], rolled(QUAD[None])[i : i + 1])[0]
        np.testing.assert_allclose(moved, square(CFG), atol=1e-3)
        np.testing.assert_allclose(moved[0], [c, c], atol=1e-3)
    np.testing.assert_allclose(to_targets(h, QUAD, CFG), 0.0, atol=1e-4)
    pts = QUAD + np.array([[1.5, -2.0], [0.5, 3.0], [-2.5, 1.0], [0.0, -1.0]])
    np.testing.assert_allclose(to_corners(back, to_targets(h, pts, CFG), CFG), pts, atol=1e-3)


def test_every_corner_of_a_square_gate_looks_the_same():
    """Turned by the gate's own homography, each corner patch shows the frame to the top left
    and the opening to the bottom right."""
    s = 60.0
    quad = np.array([[130.0, 90.0], [130 + s, 90.0], [130 + s, 90 + s], [130.0, 90 + s]])
    img = np.full((240, 320, 3), 110, np.uint8)
    img[75:166, 115:206] = (255, 90, 0)
    img[90:150, 130:190] = 110
    h, _ = homographies(quad[None], CFG)
    p = extract(img, h, CFG).astype(float)
    for i in range(1, 4):
        assert np.abs(p[i] - p[0]).mean() < 3.0
    frame, opening = p[0, 2, 2], p[0, -3, -3]
    assert frame[0] > 200 and opening[0] == pytest.approx(110, abs=2)


def test_sharpen_moves_big_gates_corners_only():
    img = gate_image()
    small = QUAD * 0.1 + 10.0  # about 9 px across
    quads = np.stack([QUAD, small])
    same = sharpen(Fixed([0.0, 0.0]), img, quads, CFG)
    np.testing.assert_allclose(same, quads, atol=1e-3)
    moved = sharpen(Fixed([0.2, 0.0]), img, quads, CFG)
    np.testing.assert_array_equal(moved[1], small)
    # 0.2 half patches towards the next corner: 0.2 * extent of the side along the edge
    step = moved[0] - QUAD
    edge = np.roll(QUAD, -1, axis=0) - QUAD
    along = (step * edge).sum(axis=1) / (edge * edge).sum(axis=1)
    np.testing.assert_allclose(along, 0.2 * CFG.extent, atol=0.01)
    assert sharpen(Fixed([0.2, 0.0]), img, np.zeros((0, 4, 2)), CFG).shape == (0, 4, 2)


def test_the_mirrored_reading_is_the_patch_mirrored_about_its_diagonal():
    y = np.array([[1.0, 2.0], [3.0, 4.0], [5.0, 6.0], [7.0, 8.0]])
    np.testing.assert_allclose(mirror_mean(y), [[3.5, 3.5], [5.5, 5.5]])

    class ReadsPatch(torch.nn.Module):
        """Answers the red of the pixel at row 2, column 5, for both coordinates."""

        def forward(self, x: torch.Tensor) -> torch.Tensor:
            return torch.stack([x[:, 0, 2, 5], x[:, 0, 2, 5]], dim=1)

    img = gate_image()
    img[..., 0] = np.arange(320)[None, :] * 3 // 4  # red ramps along x: no symmetric patch
    plain = sharpen(ReadsPatch(), img, QUAD[None], CFG)
    both = sharpen(ReadsPatch(), img, QUAD[None], replace(CFG, mirror=True))
    h, back = homographies(QUAD[None], CFG)
    p = extract(img, h, CFG)[..., 0].astype(np.float64) / 255.0
    # mirrored about the diagonal, pixel (2, 5) is read at (5, 2): each output is the mean of both
    mean = 0.5 * (p[:, 2, 5] + p[:, 5, 2])
    np.testing.assert_allclose(both[0], to_corners(back, np.stack([mean, mean], 1), CFG), atol=1e-4)
    assert not np.allclose(plain, both, atol=1e-3)


def test_a_few_training_steps_lower_the_loss():
    img = gate_image()
    rng = np.random.default_rng(0)
    quads = QUAD + rng.normal(size=(64, 4, 2)) * 3.0
    h, _ = homographies(quads, CFG)
    truth = rolled(np.repeat(QUAD[None], len(quads), 0))[:, 0]
    ex = zt.Examples(extract(img, h, CFG), to_targets(h, truth, CFG).astype(np.float32))
    net = _zoom(cfg=replace(CFG, widths=(8, 16, 16, 16), hidden=32)).train()
    opt = torch.optim.Adam(net.parameters(), 3e-3)
    sched = torch.optim.lr_scheduler.LambdaLR(opt, lambda s: 1.0)
    first = zt.train_epoch(net, opt, sched, ex, np.random.default_rng(1), 16)
    for e in range(12):
        last = zt.train_epoch(net, opt, sched, ex, np.random.default_rng(e + 2), 16)
    assert last < 0.7 * first


def test_augment_flips_patch_and_target_together():
    x = torch.zeros(64, 3, 8, 8)
    x[:, :, 1, 5] = 1.0  # a bright pixel at row 1, column 5
    y = torch.tensor([[0.5, -0.2]]).repeat(64, 1)
    xa, ya = zt.augment(x, y, np.random.default_rng(0))
    flipped = ya[:, 0] < 0
    assert 10 < flipped.sum() < 54
    assert torch.equal(ya[flipped], torch.tensor([[-0.2, 0.5]]).repeat(int(flipped.sum()), 1))
    peak = xa.mean(dim=1).flatten(1).argmax(dim=1)
    assert (peak[flipped] == 5 * 8 + 1).all() and (peak[~flipped] == 1 * 8 + 5).all()


def test_save_load_onnx_and_every_backend_give_the_same_output(tmp_path):
    onnx = pytest.importorskip("onnx")
    from onnx.reference import ReferenceEvaluator

    net = _zoom(3)
    torch.manual_seed(1)
    corner = CornerNet(TINY_MODEL).eval()
    refiner = RefineNet(RefineConfig(patch=16, margin=4, threshold=0.0)).eval()
    save_checkpoint(tmp_path / "ck", corner, DecodeConfig(), {}, refiner, None, net, {"n": 1})
    _, _, meta = load_checkpoint(tmp_path / "ck")
    loaded = load_zoom(tmp_path / "ck", meta)
    assert loaded.cfg == CFG and meta["zoom_training"]["n"] == 1
    x = torch.rand(5, 3, CFG.patch, CFG.patch)
    with torch.no_grad():
        a = net(x)
        assert torch.equal(a, loaded(x))
    export_zoom_onnx(loaded, tmp_path / "z.onnx")
    y = ReferenceEvaluator(onnx.load(str(tmp_path / "z.onnx"))).run(None, {"patches": x.numpy()})
    np.testing.assert_allclose(y[0], a.numpy(), atol=1e-4)
    img = gate_image()
    quads = np.stack([QUAD, QUAD + 40.0])
    settings = [{"frozen": True, "backend": "torch"}, {"frozen": False, "backend": "torch"},
                {"backend": "onnxruntime"}]  # fmt: skip
    dets = [CnnDetector.load(tmp_path / "ck", **kw) for kw in settings]
    assert isinstance(dets[2].zoom, OnnxRuntimeNet)
    out = [sharpen(d.zoom, img, quads, d.zoom_cfg) for d in dets]
    assert np.abs(out[0] - quads).max() > 0.01  # an untrained stage moves them
    for o in out[1:]:
        np.testing.assert_allclose(o, out[0], atol=1e-3)


def test_missing_or_corrupt_zoom_weights_name_the_file(tmp_path):
    refiner = RefineNet(RefineConfig(patch=16, margin=4))
    save_checkpoint(tmp_path / "ck", CornerNet(TINY_MODEL), DecodeConfig(), {}, refiner, None,
                    _zoom())  # fmt: skip
    (tmp_path / "ck" / "zoom.safetensors").write_bytes(b"garbage")
    with pytest.raises(ValueError, match="zoom.safetensors"):
        make_detector(f"cnn:{tmp_path / 'ck'}")
    (tmp_path / "ck" / "zoom.safetensors").unlink()
    with pytest.raises(FileNotFoundError, match="zoom.safetensors"):
        make_detector(f"cnn:{tmp_path / 'ck'}")


def _labelled_detections(detector, split, progress=False, what="", start=0):
    """Stands in for the detector: each labelled gate found a little off (seeded per image)."""
    from icarus_vision.gate_detect.cnn.data import read_rgb

    for i, path in enumerate(split.files[start:], start):
        rng = np.random.default_rng(i)
        found = [(g.corners + rng.normal(size=(4, 2)), 0.9) for g in split.gates[i]
                 if np.isfinite(g.corners).all()]  # fmt: skip
        yield i, read_rgb(path), found


def _detector(tmp_path):
    torch.manual_seed(0)
    refiner = RefineNet(RefineConfig(patch=16, margin=4))
    return save_checkpoint(tmp_path / "det", CornerNet(TINY_MODEL).eval(), DecodeConfig(), {},
                           refiner)  # fmt: skip


def test_train_zoom_saves_on_ctrl_c_resumes_exactly_and_tunes(tiny_dataset, tmp_path, monkeypatch):
    from safetensors.torch import load_file

    monkeypatch.setattr(zt, "detections", _labelled_detections)
    det = _detector(tmp_path)
    cfg = zt.ZoomTrainConfig(batch_size=32, min_gate_px=8.0)
    kw = {"zoom_config": CFG, "progress": False, "config": cfg}

    def interrupt(line: str) -> None:
        if line.startswith("epoch"):
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        zt.train_zoom(det, tiny_dataset, tmp_path / "a", epochs=2, log=interrupt, **kw)
    with pytest.raises(ValueError, match="--resume"):
        zt.train_zoom(det, tiny_dataset, tmp_path / "a", epochs=2, **kw)
    zt.train_zoom(det, tiny_dataset, tmp_path / "a", epochs=2, resume=True, progress=False)
    zt.train_zoom(det, tiny_dataset, tmp_path / "b", epochs=2, **kw)
    for kept in ("last", "best"):
        a, b = (load_file(tmp_path / r / kept / "zoom.safetensors") for r in "ab")
        assert a.keys() == b.keys() and all(torch.equal(a[k], b[k]) for k in a)
        # the detector's own networks are copied unchanged
        assert load_file(tmp_path / "a" / kept / "model.safetensors").keys() == \
            load_file(det / "model.safetensors").keys()  # fmt: skip
    meta = json.loads((tmp_path / "a" / "best" / "detector.json").read_text())
    assert meta["zoom"]["min_side_px"] in zt.MIN_SIDES and meta["zoom"]["patch"] == CFG.patch
    assert isinstance(meta["zoom"]["mirror"], bool)
    assert meta["zoom_training"]["config"]["batch_size"] == 32 and "refine" in meta
    assert meta["zoom_training"]["val"]["score"] >= meta["zoom_training"]["val_untuned"]["score"]
    assert (tmp_path / "a" / "zoom.onnx").is_file() and (tmp_path / "a" / "examples.npz").is_file()
    assert [h["epoch"] for h in json.loads((tmp_path / "a" / "history.json").read_text())] == [1, 2]
    assert make_detector(f"cnn:{tmp_path / 'a' / 'best'}").zoom is not None


def test_train_zoom_interrupted_while_cutting_patches_continues_from_its_parts(
    tiny_dataset, tmp_path, monkeypatch
):
    monkeypatch.setattr(zt, "CHUNK", 3)  # 8 training images: parts of 3, 3 and 2
    seen = []

    def detections(detector, split, progress=False, what="", start=0):
        for item in _labelled_detections(detector, split, progress, what, start):
            if what.startswith("train"):
                seen.append(item[0])
                if len(seen) == 5 and interrupting:  # in the second part
                    raise KeyboardInterrupt
            yield item

    monkeypatch.setattr(zt, "detections", detections)
    det = _detector(tmp_path)
    kw = {"zoom_config": CFG, "progress": False, "epochs": 1,
          "config": zt.ZoomTrainConfig(batch_size=32, min_gate_px=8.0)}  # fmt: skip
    interrupting = True
    with pytest.raises(KeyboardInterrupt):
        zt.train_zoom(det, tiny_dataset, tmp_path / "a", **kw)
    assert sorted(p.name for p in (tmp_path / "a" / zt.PARTS / "0").iterdir()) == ["00000.npz"]
    interrupting, seen[:] = False, []
    zt.train_zoom(det, tiny_dataset, tmp_path / "a", **kw)  # the same command again
    assert seen == [3, 4, 5, 6, 7]  # the first part was read, not cut again
    assert not (tmp_path / "a" / zt.PARTS).exists()
    zt.train_zoom(det, tiny_dataset, tmp_path / "b", **kw)
    with np.load(tmp_path / "a" / zt.EXAMPLES) as a, np.load(tmp_path / "b" / zt.EXAMPLES) as b:
        assert len(a["targets"]) > 0
        assert np.array_equal(a["patches"], b["patches"])
        assert np.array_equal(a["targets"], b["targets"])


def test_a_finished_run_resumed_is_only_tuned_again(tiny_dataset, tmp_path, monkeypatch):
    from safetensors.torch import load_file

    monkeypatch.setattr(zt, "detections", _labelled_detections)
    det = _detector(tmp_path)
    cfg = zt.ZoomTrainConfig(batch_size=32, min_gate_px=8.0)
    zt.train_zoom(det, tiny_dataset, tmp_path / "a", epochs=1, zoom_config=CFG, config=cfg,
                  progress=False)  # fmt: skip
    before = load_file(tmp_path / "a" / "best" / "zoom.safetensors")
    (tmp_path / "a" / "examples.npz").unlink()

    def no_training(*args, **kwargs):
        raise AssertionError("a finished run needs no training patches")

    monkeypatch.setattr(zt, "training_examples", no_training)
    zt.train_zoom(det, tiny_dataset, tmp_path / "a", epochs=1, resume=True, progress=False)
    after = load_file(tmp_path / "a" / "best" / "zoom.safetensors")
    assert all(torch.equal(before[k], after[k]) for k in before)
    meta = json.loads((tmp_path / "a" / "best" / "detector.json").read_text())
    assert meta["zoom_training"]["val_untuned"]["min_side_px"] == CFG.min_side_px


def test_training_examples_are_the_matched_gates_corners(tiny_dataset, monkeypatch):
    monkeypatch.setattr(zt, "detections", _labelled_detections)
    split = load_split(tiny_dataset, "train")
    cfg = zt.ZoomTrainConfig(copies=1, min_gate_px=8.0)
    counted = sum(len(found) for _, _, found in _labelled_detections(None, split))
    ex = zt.training_examples(None, split, CFG, cfg, np.random.default_rng(0))
    assert ex.patches.shape[1:] == (CFG.patch, CFG.patch, 3) and len(ex.patches) == len(ex.targets)
    assert 0 < len(ex.targets) <= 2 * 4 * counted
    assert np.isfinite(ex.targets).all() and (np.abs(ex.targets) < 1.5).all()


def test_wide_copies_move_one_corner_far_and_leave_the_other_copies_as_they_were():
    narrow = zt.ZoomTrainConfig(copies=2, jitter=0.02)
    wide = replace(narrow, wide_copies=4000, wide_jitter=0.15)
    before = zt.corner_noise(narrow, np.random.default_rng(3))
    noise = zt.corner_noise(wide, np.random.default_rng(3))
    assert noise.shape == (4002, 4, 2)
    assert np.array_equal(noise[:2], before)  # the narrow copies: the same draws
    far = np.linalg.norm(noise[2:], axis=-1)  # (4000, 4)
    moved = far.argmax(axis=1)  # the wide corner (a narrow one where the wide draw was small)
    assert np.bincount(moved, minlength=4).min() > 800  # each corner is moved in some copies
    rest = np.sort(far, axis=1)[:, :3]
    assert np.median(far.max(axis=1)) > 0.15 > np.percentile(rest, 99)
    assert 0.017 < np.sqrt((rest**2).mean() / 2) < 0.023  # the narrow spread


def test_train_zoom_needs_a_refiner(tiny_dataset, tmp_path):
    det = save_checkpoint(tmp_path / "det", CornerNet(TINY_MODEL), DecodeConfig())
    with pytest.raises(ValueError, match="refiner"):
        zt.train_zoom(det, tiny_dataset, tmp_path / "a", epochs=1, progress=False)


def test_the_squareness_check_takes_the_zoomed_corners(monkeypatch):
    """With a zoom stage, the refiner selects without the check and the detector checks the
    corners the zoom stage moved: what it reports is square in 3-D, not what the refiner saw."""
    import icarus_vision.gate_detect.cnn as cnn

    square, wide = facing_box(48, 48, 60), facing_box(64, 40, 250)
    small_wide = facing_box(24, 15, 160)
    refined = [(wide, np.ones(4), 0.9), (facing_box(40, 40, 250), np.ones(4), 0.8),
               (small_wide, np.ones(4), 0.7)]  # fmt: skip
    zoomed = np.stack([square, wide, small_wide])  # the first becomes square, the second not
    seen = {}

    def fake_refine(net, image, cand, peaks, cfg, nms_iou):
        seen["cfg"] = cfg
        return refined

    monkeypatch.setattr(cnn, "refine", fake_refine)
    monkeypatch.setattr(cnn, "sharpen", lambda net, image, quads, cfg: zoomed)
    refiner = RefineNet(RefineConfig(patch=16, margin=4, max_skew=0.4, skew_min_px=30.0))
    det = CnnDetector(CornerNet(TINY_MODEL), refiner=refiner, zoom=_zoom(), backend="torch")
    found = det.detect(gate_image())
    assert seen["cfg"].max_skew == 0.0 and det.refine_cfg.max_skew == 0.4
    # the square one and the small one (under skew_min_px) are kept, the one zoomed wide dropped
    np.testing.assert_array_equal([d.corners for d in found], [square, small_wide])
    assert [d.score for d in found] == [0.9, 0.7]
