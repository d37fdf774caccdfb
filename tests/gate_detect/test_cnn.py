"""The CNN: target encoding/decoding, augmentation, a few training steps, save/load, ONNX."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from icarus_vision.gate_detect import make_detector
from icarus_vision.gate_detect.cnn import CnnDetector
from icarus_vision.gate_detect.cnn.augment import make_augment
from icarus_vision.gate_detect.cnn.checkpoint import export_onnx, load_checkpoint, save_checkpoint
from icarus_vision.gate_detect.cnn.data import GateDataset, load_split, load_splits, mirror
from icarus_vision.gate_detect.cnn.decode import (
    DecodeConfig,
    decode,
    in_frame,
    nested_gates,
    peak_maps,
    snap,
)
from icarus_vision.gate_detect.cnn.model import CornerNet, ModelConfig
from icarus_vision.gate_detect.cnn.targets import detection_loss, encode_targets, focal_loss
from icarus_vision.gate_detect.cnn.tune import choose
from tests.gate_detect.conftest import TINY_MODEL

GATE_A = np.array([[30.3, 20.6], [52.2, 21.4], [51.7, 44.9], [29.1, 43.2]])  # grid units
GATE_B = np.array([[60.4, 30.2], [66.8, 30.5], [66.6, 36.9], [60.1, 36.6]])
VIS = np.array([2, 2, 2, 2])


def _as_logits(target: np.ndarray) -> torch.Tensor:
    t = torch.from_numpy(target.copy())
    t[:5] = torch.logit(t[:5].clamp(1e-4, 1 - 1e-4))
    return t


def test_encode_then_decode_recovers_two_gates():
    target, weight = encode_targets([(GATE_A, VIS), (GATE_B, VIS)], 80, 60)
    assert target[0].max() == 1.0 and (target[1:5] == 1.0).sum() == 8
    found = decode(_as_logits(target), DecodeConfig(), (4.0, 4.0))
    assert len(found) == 2
    for truth in (GATE_A, GATE_B):
        px = truth * 4.0 - 0.5
        err = min(np.abs(c - px).max() for c, _, _ in found)
        assert err < 1e-3


def test_a_gate_found_twice_is_reported_once():
    target, _ = encode_targets([(GATE_A, VIS)], 80, 60)
    logits = _as_logits(target)
    # A second centre peak two cells right of the first, predicting the same corners.
    logits[0, 32, 42] = logits[0].max() - 0.1
    logits[7:15, 32, 42] = torch.from_numpy(((GATE_A - (42, 32)) / 8.0).reshape(-1))
    assert len(decode(logits, DecodeConfig(), (4.0, 4.0))) == 1
    assert len(decode(logits, DecodeConfig(nms_iou=1.0, nested=False), (4.0, 4.0))) == 2


def test_a_gate_seen_through_another_is_found_though_they_share_a_centre():
    far = (GATE_A - GATE_A.mean(axis=0)) * 0.4 + GATE_A.mean(axis=0) + (0.1, 0.05)
    target, _ = encode_targets([(GATE_A, VIS), (far, VIS)], 80, 60)
    logits = _as_logits(target)  # the shared centre cell regresses only the near gate
    assert len(decode(logits, DecodeConfig(nested=False), (4.0, 4.0))) == 1
    found = decode(logits, DecodeConfig(), (4.0, 4.0))
    assert len(found) == 2
    for truth in (GATE_A, far):
        assert min(np.abs(c - (truth * 4.0 - 0.5)).max() for c, _, _ in found) < 1e-3


def test_a_nested_gate_of_another_shape_needs_a_looser_fit():
    far = (GATE_A - GATE_A.mean(axis=0)) * 0.4 + GATE_A.mean(axis=0) + (0.1, 0.05)
    far[1] += (1.5, 0.0)  # seen from another angle: TR and BL pulled apart
    far[3] -= (1.5, 0.0)
    target, _ = encode_targets([(GATE_A, VIS), (far, VIS)], 80, 60)
    logits = _as_logits(target)
    assert len(decode(logits, DecodeConfig(nested_residual=0.05), (4.0, 4.0))) == 1
    found = decode(logits, DecodeConfig(nested_residual=0.08), (4.0, 4.0))
    assert len(found) == 2
    assert min(np.abs(c - (far * 4.0 - 0.5)).max() for c, _, _ in found) < 1e-3


def test_a_gate_whose_corners_do_not_show_is_kept_only_if_its_centre_is_sure():
    target, _ = encode_targets([(GATE_A, VIS)], 80, 60)
    logits = _as_logits(target)
    logits[1:5] = -10.0  # no corner peaks: nothing confirms the regressed corners
    logits[0] -= logits[0].max() - float(torch.logit(torch.tensor(0.7)))  # centre peak 0.7
    assert len(decode(logits, DecodeConfig(min_snapped=3), (4.0, 4.0))) == 0
    assert len(decode(logits, DecodeConfig(min_snapped=3, sure_centre=0.6), (4.0, 4.0))) == 1
    assert len(decode(logits, DecodeConfig(min_snapped=3, sure_centre=0.8), (4.0, 4.0))) == 0


def test_small_gates_can_be_ignored_rather_than_learned():
    small = GATE_B * 0.5 + (20.0, 5.0)  # mean side about 3.2 cells
    target, weight = encode_targets([(GATE_A, VIS), (small, VIS)], 80, 60, ignore_below=4.0)
    assert (target[1:5] == 1.0).sum() == 4 and (target[0] == 1.0).sum() == 1  # GATE_A only
    x0, y0 = np.floor(small.min(axis=0)).astype(int)
    x1, y1 = np.floor(small.max(axis=0)).astype(int)
    assert weight[2, y0 - 1 : y1 + 2, x0 - 1 : x1 + 2].min() == 1.0
    assert weight[2].sum() == (x1 - x0 + 3) * (y1 - y0 + 3)
    # A peak over the ignored gate costs nothing; the same peak elsewhere does.
    quiet = torch.full((1, 1, 60, 80), -9.0)
    t = torch.from_numpy(target[None, 1:2])
    ign = torch.from_numpy(weight[None, 2:3])
    base = focal_loss(quiet, t, ign)
    over_small, elsewhere = quiet.clone(), quiet.clone()
    over_small[..., int(small[0, 1]), int(small[0, 0])] = 3.0
    elsewhere[..., 50, 70] = 3.0
    assert float(focal_loss(over_small, t, ign)) == pytest.approx(float(base), rel=1e-6)
    assert float(focal_loss(elsewhere, t, ign)) > float(base) + 1.0
    no_ignore, _ = encode_targets([(GATE_A, VIS), (small, VIS)], 80, 60)
    assert (no_ignore[1:5] == 1.0).sum() == 8


def test_decode_tuning_prefers_fewer_detections_among_equal_scores():
    def metrics(precision: float, recall: float, detections: int) -> dict:
        pck = {"5px": 0.9, "2px": 0.7}
        return {"precision": precision, "recall": recall, "pck": pck, "detections": detections}

    low, mid, high = (DecodeConfig(centre_threshold=c) for c in (0.2, 0.3, 0.5))
    best = (low, metrics(0.90, 0.95, 120))  # score 0.8625
    tie = (mid, metrics(0.91, 0.9396, 110))  # 0.8624: within SCORE_TIE, fewer detections
    worse = (high, metrics(0.95, 0.85, 80))  # 0.85: fewest detections, but worse
    assert choose([best, tie, worse])[0] is mid
    assert choose([best, worse])[0] is low


def test_stem_puts_the_output_at_input_stride_4():
    cfg = ModelConfig(input_size=(64, 48), image_size=(64, 48), widths=(4, 4, 8, 8), head_width=4,
                      stem_width=4)  # fmt: skip
    assert cfg.grid == (16, 12) and cfg.stride == 4.0
    assert CornerNet(cfg)(torch.rand(1, 3, 48, 64)).shape == (1, 15, 12, 16)
    old = {k: v for k, v in cfg.to_dict().items() if k != "stem_width"}
    assert ModelConfig.from_dict(old).stem_width == 0  # files from before the stem


def test_hidden_corner_falls_back_on_the_regressed_vector():
    vis = np.array([2, 2, 1, 2])
    target, _ = encode_targets([(GATE_A, vis)], 80, 60)
    ((corners, scores, _),) = decode(_as_logits(target), DecodeConfig(), (4.0, 4.0))
    assert scores[2] == 0.0 and scores[[0, 1, 3]].min() > 0.9
    np.testing.assert_allclose(corners, GATE_A * 4.0 - 0.5, atol=1e-3)
    assert len(decode(_as_logits(target), DecodeConfig(min_snapped=3), (4.0, 4.0))) == 1
    assert decode(_as_logits(target), DecodeConfig(min_snapped=4), (4.0, 4.0)) == []


def test_augmentation_keeps_keypoints_on_the_gate_corners():
    """A white square on black: after every augmentation the keypoints still sit on its corners."""
    img = np.zeros((120, 160, 3), np.uint8)
    img[40:80, 60:100] = 255
    kps = np.array([[60.0, 40.0], [100.0, 40.0], [100.0, 80.0], [60.0, 80.0]])  # continuous coords
    aug = make_augment(seed=3)
    for _ in range(30):
        out = aug(image=img, keypoints=kps)
        grey = out["image"].mean(axis=2)
        thr = 0.5 * (np.percentile(grey, 1) + np.percentile(grey, 99))
        for x, y in np.asarray(out["keypoints"]):
            u, v = int(round(x - 0.5)), int(round(y - 0.5))
            if 2 <= u < 158 and 2 <= v < 118:
                win = grey[v - 2 : v + 3, u - 2 : u + 3] > thr
                assert win.any() and not win.all(), (x, y)


def test_mirror_swaps_left_and_right_corners():
    img = np.zeros((120, 160, 3), np.uint8)
    img[10, 0] = 255
    kps = np.array([[[40.0, 30.0], [80.0, 32.0], [78.0, 70.0], [np.nan, 68.0]]])
    vis = np.array([[2, 1, 2, 0]])
    m_img, m_kps, m_vis = mirror(img, kps, vis)
    assert m_img[10, 159].all()
    np.testing.assert_allclose(
        m_kps[0], [[80.0, 32.0], [120.0, 30.0], [np.nan, 68.0], [82.0, 70.0]]
    )
    assert m_vis.tolist() == [[1, 2, 0, 2]]


def test_dataset_sample_has_peaks_at_the_gate_corners(tiny_dataset):
    split = load_split(tiny_dataset, "train", TINY_MODEL.input_size)
    i = next(i for i, g in enumerate(split.gates) if any((x.visibility == 2).all() for x in g))
    gate = next(g for g in split.gates[i] if (g.visibility == 2).all())
    _, target, _ = GateDataset(split, (40, 30), augment=False)[i]
    for k in range(4):
        cell = np.floor((gate.corners[k] + 0.5) / 4.0).astype(int)  # 160 px -> 40 cells
        if 0 <= cell[0] < 40 and 0 <= cell[1] < 30:
            assert target[1 + k, cell[1], cell[0]] == 1.0


def test_several_datasets_load_as_one_split(tiny_dataset, tmp_path):
    import json
    import shutil

    one = load_split(tiny_dataset, "train", (80, 60))
    both = load_splits([tiny_dataset, tiny_dataset], "train", (80, 60))
    assert both.files == one.files * 2 and len(both.gates) == 2 * len(one.gates)
    np.testing.assert_array_equal(both.images, np.concatenate([one.images, one.images]))
    assert load_splits([tiny_dataset], "val").images is None
    other = tmp_path / "other"
    shutil.copytree(tiny_dataset, other)
    ann = other / "annotations" / "train.json"
    coco = json.loads(ann.read_text())
    for im in coco["images"]:
        im["width"] = 320
    ann.write_text(json.dumps(coco))
    with pytest.raises(ValueError, match="different image sizes"):
        load_splits([tiny_dataset, other], "train", (80, 60))


def test_a_split_mapped_from_disk_holds_the_same_images_and_is_reused(tiny_dataset, tmp_path):
    import os
    import shutil

    import cv2

    data = tmp_path / "data"
    shutil.copytree(tiny_dataset, data)
    held = load_splits([data], "train", (80, 60))
    npy = tmp_path / "cache" / "train.npy"
    mapped = load_splits([data], "train", (80, 60), disk=npy)
    assert isinstance(mapped.images, np.memmap) and not mapped.images.flags.writeable
    np.testing.assert_array_equal(mapped.images, held.images)
    written = npy.stat().st_mtime_ns
    again = load_splits([data], "train", (80, 60), disk=npy)
    assert npy.stat().st_mtime_ns == written  # the same images: read, not written again
    np.testing.assert_array_equal(again.images, held.images)
    # an image changed on disk: written again, with the new pixels
    first = held.files[0]
    flipped = cv2.imread(str(first))[::-1].copy()
    cv2.imwrite(str(first), flipped)
    os.utime(first, ns=(written + 10**9, written + 10**9))
    fresh = load_splits([data], "train", (80, 60), disk=npy)
    np.testing.assert_array_equal(fresh.images[0], load_split(data, "train", (80, 60)).images[0])
    assert not np.array_equal(fresh.images[0], held.images[0])
    # a corrupt cache file is written again, not trusted
    npy.write_bytes(b"not an array")
    np.testing.assert_array_equal(load_splits([data], "train", (80, 60), disk=npy).images[1:],
                                  held.images[1:])  # fmt: skip


def test_a_few_training_steps_lower_the_loss(tiny_dataset):
    torch.manual_seed(0)
    split = load_split(tiny_dataset, "train", TINY_MODEL.input_size)
    ds = GateDataset(split, (40, 30), augment=False)
    x, t, w = (
        torch.from_numpy(np.stack(a)) for a in zip(*[ds[i] for i in range(len(ds))], strict=True)
    )
    model = CornerNet(TINY_MODEL)
    opt = torch.optim.Adam(model.parameters(), 3e-3)
    losses = []
    for _ in range(25):
        loss = detection_loss(model(x), t, w)["loss"]
        opt.zero_grad()
        loss.backward()
        opt.step()
        losses.append(float(loss.detach()))
    assert losses[-1] < 0.7 * losses[0]


def test_save_load_and_onnx_give_the_same_output(tmp_path):
    onnx = pytest.importorskip("onnx")
    from onnx.reference import ReferenceEvaluator

    torch.manual_seed(1)
    model = CornerNet(TINY_MODEL).eval()
    save_checkpoint(tmp_path / "ck", model, DecodeConfig(centre_threshold=0.2), {"note": "x"})
    loaded, dec, meta = load_checkpoint(tmp_path / "ck" / "model.safetensors")
    assert dec.centre_threshold == 0.2 and meta["training"]["note"] == "x"
    x = torch.rand(2, 3, 60, 80)
    with torch.no_grad():
        a, b = model(x), loaded(x)
    assert torch.equal(a, b)
    export_onnx(loaded, tmp_path / "m.onnx")
    sess = ReferenceEvaluator(onnx.load(str(tmp_path / "m.onnx")))
    y = sess.run(None, {"image": x[:1].numpy()})[0]
    np.testing.assert_allclose(y, a[:1].numpy(), atol=1e-4)
    # the detector folds batch norm: same detections as the unfused network's maps
    det = CnnDetector(loaded, DecodeConfig(centre_threshold=0.0))
    img = (x[0].numpy().transpose(1, 2, 0) * 255).astype(np.uint8)
    assert len(det.detect(img)) > 0


def test_missing_or_corrupt_checkpoint_names_the_file(tmp_path):
    with pytest.raises(FileNotFoundError, match="nowhere"):
        make_detector(f"cnn:{tmp_path / 'nowhere'}")
    save_checkpoint(tmp_path / "ck", CornerNet(TINY_MODEL), DecodeConfig())
    (tmp_path / "ck" / "model.safetensors").write_bytes(b"not safetensors at all")
    with pytest.raises(ValueError, match="model.safetensors"):
        make_detector(f"cnn:{tmp_path / 'ck'}")
    (tmp_path / "ck" / "detector.json").write_text("{broken")
    with pytest.raises(ValueError, match="detector.json"):
        make_detector(f"cnn:{tmp_path / 'ck'}")
    (tmp_path / "ck" / "detector.json").unlink()
    with pytest.raises(FileNotFoundError, match="detector.json"):
        make_detector(f"cnn:{tmp_path / 'ck'}")


def test_shipped_default_loads_and_is_small():
    from icarus_vision.gate_detect.cnn.checkpoint import SHIPPED

    det = make_detector("cnn")
    assert isinstance(det, CnnDetector)
    size = sum(f.stat().st_size for f in SHIPPED.iterdir())
    # "a few MB at most": 7.8 MiB since the int8 copies (float32: corner network 2.9, refiner
    # 2.3, zoom stage 0.9 MiB; int8: 0.8, 0.6, 0.3 MiB)
    assert size < 8.5 * 2**20


def test_train_detector_writes_checkpoints_saves_on_ctrl_c_and_resumes(tiny_dataset, tmp_path):
    from icarus_vision.gate_detect.cnn.train import TrainConfig, train_detector

    out = tmp_path / "run"
    cfg = TrainConfig(batch_size=4, bf16=False, ignore_below_px=5.0)

    def interrupt(line: str) -> None:
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        train_detector(tiny_dataset, out, epochs=2, config=cfg, model_config=TINY_MODEL,
                       progress=False, log=interrupt)  # fmt: skip
    assert (out / "last" / "train_state.pt").is_file() and (
        out / "best" / "detector.json"
    ).is_file()
    with pytest.raises(ValueError, match="--resume"):
        train_detector(tiny_dataset, out, epochs=2, config=cfg, progress=False)
    lines = []
    r = train_detector(tiny_dataset, out, epochs=2, resume=True, config=TrainConfig(),
                       progress=False, log=lines.append)  # fmt: skip
    stored = json.loads((out / "last" / "detector.json").read_text())["training"]["config"]
    assert stored["ignore_below_px"] == 5.0 and stored["batch_size"] == 4  # the run's own settings
    assert r.epochs_done == 2 and lines[0].startswith("epoch 2") and "tuned" in lines[1]
    assert [h["epoch"] for h in json.loads((out / "history.json").read_text())] == [1, 2]
    assert (out / "model.onnx").is_file() and any((out / "tb").iterdir())
    det = make_detector(f"cnn:{out / 'best'}")
    assert isinstance(det.detect(np.zeros((120, 160, 3), np.uint8)), list)
    # Resuming a finished run only tunes the decoding again (after the tuning grid changed).
    first = json.loads((out / "best" / "detector.json").read_text())["training"]
    lines = []
    train_detector(tiny_dataset, out, epochs=2, resume=True, config=cfg, progress=False,
                   log=lines.append)  # fmt: skip
    again = json.loads((out / "best" / "detector.json").read_text())["training"]
    assert len(lines) == 1 and "tuned" in lines[0]
    assert again["epoch"] == first["epoch"]
    assert again["val_default_decode"] == first["val_default_decode"]


@pytest.mark.parametrize("ema_decay", [0.0, 0.9])
def test_resumed_training_equals_an_uninterrupted_run(tiny_dataset, tmp_path, ema_decay):
    from safetensors.torch import load_file

    from icarus_vision.gate_detect.cnn.train import TrainConfig, train_detector

    cfg = TrainConfig(batch_size=4, bf16=False, tune_decode=False, ema_decay=ema_decay)

    def interrupt(line: str) -> None:
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        train_detector(tiny_dataset, tmp_path / "a", epochs=2, config=cfg,
                       model_config=TINY_MODEL, progress=False, log=interrupt)  # fmt: skip
    train_detector(tiny_dataset, tmp_path / "a", epochs=2, resume=True, progress=False)
    train_detector(tiny_dataset, tmp_path / "b", epochs=2, config=cfg, model_config=TINY_MODEL,
                   progress=False)  # fmt: skip
    for kept in ("last", "best"):  # best: the moving average, if any
        a, b = (load_file(tmp_path / r / kept / "model.safetensors") for r in "ab")
        assert a.keys() == b.keys()
        assert all(torch.equal(a[k], b[k]) for k in a)


@pytest.mark.parametrize("pos", [(0.0, 0.0, 2.0), (-2.0, 0.0, 2.0), (0.5, 0.6, 2.3)])
def test_shipped_cnn_finds_a_rendered_gate(pos):
    from icarus_vision.render.camera import Camera
    from icarus_vision.render.scene import Scene
    from icarus_vision.sim.track import Gate, Track

    track = Track("one", (Gate((4.0, 0.0, 2.0)),), start_pos=(0.0, 0.0, 0.2))
    cam = Camera(uptilt_deg=0.0)
    quat = np.array([0.0, 0.0, 0.0, 1.0])
    with Scene(track, cam) as scene:
        frame = scene.render(np.array(pos), quat)
    truth, _ = cam.project(track.gates[0].corners(), np.array(pos), quat)
    # float32 on both backends, and bfloat16 (native or emulated)
    for settings in (
        {"backend": "torch", "bf16": False},
        {"backend": "onnxruntime"},
        {"bf16": True},
    ):
        found = CnnDetector.load(**settings).detect(frame.rgb)
        assert len(found) == 1
        assert np.linalg.norm(found[0].corners - truth, axis=1).max() < 3.0


def test_fine_tuning_starts_from_a_checkpoint_at_another_input_size(tiny_dataset, tmp_path):
    from dataclasses import replace

    from icarus_vision.gate_detect.cnn.train import TrainConfig, train_detector

    torch.manual_seed(0)
    start = CornerNet(TINY_MODEL).eval()
    save_checkpoint(tmp_path / "start", start, DecodeConfig())
    cfg = TrainConfig(batch_size=4, bf16=False, tune_decode=False, lr=0.0)  # weights kept
    other = replace(ModelConfig(), input_size=(64, 48))  # only its input size is taken
    train_detector(tiny_dataset, tmp_path / "ft", epochs=1, config=cfg, model_config=other,
                   init=tmp_path / "start", progress=False)  # fmt: skip
    model, _, meta = load_checkpoint(tmp_path / "ft" / "last")
    assert model.cfg == replace(TINY_MODEL, input_size=(64, 48))
    assert meta["training"]["init"] == str(tmp_path / "start")
    with torch.no_grad():  # same weights (lr 0: only batch-norm statistics move)
        assert all(
            torch.equal(a, b) for a, b in zip(model.parameters(), start.parameters(), strict=True)
        )


def test_peaks_are_found_per_map_with_no_map_seeing_the_next():
    heat = np.zeros((3, 6, 5), np.float32)
    heat[0, 5, 2] = 0.5  # last row of map 0 ...
    heat[1, 0, 2] = 0.9  # ... next to the first row of map 1 in memory
    heat[1, 3, 3] = 0.4
    heat[2, 2, 1], heat[2, 2, 2] = 0.6, 0.7  # a plateau's slope is no peak
    ks, ys, xs = peak_maps(heat, np.array([0.3, 0.3, 0.65], np.float32))
    assert list(zip(ks.tolist(), ys.tolist(), xs.tolist(), strict=True)) == [
        (0, 5, 2), (1, 0, 2), (1, 3, 3), (2, 2, 2)
    ]  # fmt: skip


def test_each_corner_snaps_to_the_nearest_peak_of_its_type_within_the_radius():
    gates = np.stack([GATE_A, GATE_B])
    pos = np.array([GATE_A[0] + (0.5, 0.0), GATE_A[0] + (0.2, 0.1), GATE_A[1] + (0.3, 0.0),
                    GATE_B[2] + (3.0, 0.0), GATE_B[3] + (0.1, 0.1)])  # fmt: skip
    kind = np.array([0, 0, 2, 2, 3])  # the third is near TR but is a BR peak
    val = np.array([0.5, 0.6, 0.7, 0.8, 0.9])
    corners, scores = snap(gates, (pos, kind, val), 0.3)  # GATE_B's radius: 1.9 cells
    np.testing.assert_array_equal(corners[0, 0], pos[1])
    np.testing.assert_array_equal(corners[0, 1:], GATE_A[1:])
    np.testing.assert_array_equal(corners[1, :3], GATE_B[:3])
    np.testing.assert_array_equal(corners[1, 3], pos[4])
    np.testing.assert_array_equal(scores, [[0.6, 0, 0, 0], [0, 0, 0, 0.9]])
    np.testing.assert_array_equal(snap(gates, (pos[:0], kind[:0], val[:0]), 0.3)[0], gates)


def test_nested_gates_of_several_centres_are_those_of_each_alone():
    far = (GATE_A - GATE_A.mean(axis=0)) * 0.4 + GATE_A.mean(axis=0) + (0.1, 0.05)
    near_b = (GATE_B - GATE_B.mean(axis=0)) * 2.0 + GATE_B.mean(axis=0)
    peaks = np.concatenate([far, near_b, GATE_A[:2] + 0.2])
    z = peaks[:, 0] + 1j * peaks[:, 1]
    kind = np.array([0, 1, 2, 3, 0, 1, 2, 3, 0, 1])
    val = np.linspace(0.3, 0.9, len(z))
    centres = np.stack([GATE_A.mean(axis=0), GATE_B.mean(axis=0), (5.0, 5.0)])
    vectors = np.stack([GATE_A, GATE_B, GATE_B - GATE_B.mean(axis=0) + 5.0]) - centres[:, None]
    together = nested_gates(centres, vectors, (z, kind, val), 0.08)
    assert len(together[0]) and len(together[1]) and not together[2]
    for i, found in enumerate(together):
        alone = nested_gates(centres[i : i + 1], vectors[i : i + 1], (z, kind, val), 0.08)[0]
        assert len(alone) == len(found)
        for (c, s), (c1, s1) in zip(found, alone, strict=True):
            np.testing.assert_array_equal(c, c1)
            np.testing.assert_array_equal(s, s1)
    assert min(np.abs(c - far).max() for c, _ in together[0]) < 1e-9
    assert min(np.abs(c - near_b).max() for c, _ in together[1]) < 1e-9


def test_an_unknown_split_is_named_with_the_ones_there_are(tiny_dataset):
    with pytest.raises(ValueError, match="split must be one of train, val, test, got 'tset'"):
        load_split(tiny_dataset, "tset")


def test_gates_cut_by_the_frame_edge_are_candidates_but_not_reported():
    cut = GATE_A - (35.0, 0.0)  # its left corners 5 grid cells (20 px) left of the image
    logits = _as_logits(encode_targets([(cut, VIS), (GATE_B, VIS)], 80, 60)[0])
    everywhere = decode(logits, DecodeConfig(max_outside_px=None), (4.0, 4.0))
    assert len(everywhere) == 2 and min(c[:, 0].min() for c, _, _ in everywhere) < -15.0
    found = decode(logits, DecodeConfig(), (4.0, 4.0))
    assert len(found) == 1 and np.abs(found[0][0] - (GATE_B * 4.0 - 0.5)).max() < 1e-3
    candidates, _ = decode(logits, DecodeConfig(), (4.0, 4.0), with_peaks=True)
    assert len(candidates) == 2  # the refiner may still move a candidate's corners in


def test_in_frame_allows_corners_up_to_the_margin_outside_the_image():
    def gate(dx: float) -> tuple:  # left corners at x = -0.5 - dx: dx px outside the image
        c = np.array([[-0.5 - dx, 10.0], [40.0, 10.0], [40.0, 50.0], [-0.5 - dx, 50.0]])
        return (c, np.ones(4), 0.9)

    found = [gate(0.0), gate(1.4), gate(1.6), gate(-3.0)]
    assert [f[0][0, 0] for f in in_frame(found, (320, 240), 1.5)] == [-0.5, -1.9, 2.5]
    assert in_frame(found, (320, 240), None) == found
    bottom = (np.array([[10.0, 200.0], [50.0, 200.0], [50.0, 241.0], [10.0, 241.0]]), None, 1.0)
    assert in_frame([bottom], (320, 240), 1.5) == [bottom] and not in_frame(
        [bottom], (320, 240), 1.0
    )


def test_degenerate_network_outputs_decode_without_error():
    logits = _as_logits(encode_targets([(GATE_A, VIS), (GATE_B, VIS)], 80, 60)[0])
    collapsed = logits.clone()
    collapsed[7:] = 0.0  # every centre-to-corner vector zero: nothing to fit nested gates to
    assert all(np.isfinite(c).all() for c, _, _ in decode(collapsed, DecodeConfig(), (4.0, 4.0)))
    broken = logits.clone()
    broken[:, 30:40] = float("nan")  # NaN and inf where a gate is
    broken[7:, 45:50] = float("inf")
    decode(broken, DecodeConfig(), (4.0, 4.0), with_peaks=True)
    rng = np.random.default_rng(0)
    noise = torch.from_numpy(rng.normal(0.0, 3.0, (15, 60, 80)).astype(np.float32))
    gates = decode(noise, DecodeConfig(max_gates=20), (4.0, 4.0))
    assert len(gates) <= 20


def test_training_mixes_renders_and_real_images_by_share(tiny_dataset, tmp_path):
    """A gen-dataset and a COCO folder of another image size (real images, import-gates) in one
    run: the COCO folder joins training only, each source gets its share of the draws, and the
    run records its sources; a share that is not > 0 is refused on the command line."""
    import cv2
    from typer.testing import CliRunner

    from icarus_vision.cli import app
    from icarus_vision.gate_detect.cnn.data import load_splits
    from icarus_vision.gate_detect.cnn.train import TrainConfig, data_sources, train_detector
    from tests.gate_detect.conftest import QUAD, gate_image

    real = tmp_path / "real"
    (real / "images").mkdir(parents=True)
    for n in range(3):
        wide = np.concatenate([gate_image(), np.full((240, 120, 3), 110, np.uint8)], axis=1)
        cv2.imwrite(str(real / "images" / f"r{n}.png"), wide)
    (real / "labels.json").write_text(
        json.dumps({f"r{n}.png": [QUAD.ravel().tolist()] for n in range(3)})
    )
    coco = tmp_path / "coco"
    assert (
        CliRunner()
        .invoke(app, ["import-gates", str(real), "--format", "alphapilot", "--out", str(coco)])
        .exit_code
        == 0
    )

    train = load_splits([tiny_dataset, coco], "train", (80, 60), shares=[3.0, 1.0], same_size=False)
    assert len(train.files) == 8 + 3 and train.size_of(8) == (440, 240)
    np.testing.assert_allclose([train.weights[:8].sum(), train.weights[8:].sum()], [3.0, 1.0])
    val = load_splits([tiny_dataset, coco], "val", (80, 60), same_size=False)
    assert len(val.files) == 4  # the COCO folder has no val split

    out = tmp_path / "run"
    cfg = TrainConfig(batch_size=4, bf16=False, tune_decode=False)
    r = train_detector([(tiny_dataset, 3.0), (coco, 1.0)], out, epochs=1, config=cfg,
                       model_config=TINY_MODEL, progress=False)  # fmt: skip
    assert data_sources([str(tiny_dataset), (coco, 2)]) == [(tiny_dataset, 1.0), (coco, 2.0)]
    stored = json.loads((out / "best" / "detector.json").read_text())["training"]["data"]
    assert stored == [[str(tiny_dataset), 3.0], [str(coco), 1.0]] and r.epochs_done == 1
    bad = CliRunner().invoke(
        app, ["train-detector", "--data", f"{coco}:0", "--out", str(tmp_path / "o")]
    )
    assert bad.exit_code == 1 and "share" in bad.output
