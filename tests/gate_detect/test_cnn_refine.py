"""The detector's second stage: rectified patches, corner corrections, training and checkpoints."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest
import torch

from icarus_vision.gate_detect import make_detector
from icarus_vision.gate_detect.base import FLIP_ORDER
from icarus_vision.gate_detect.cnn import CnnDetector, OnnxRuntimeNet
from icarus_vision.gate_detect.cnn import refine_train as rt
from icarus_vision.gate_detect.cnn.checkpoint import (
    export_refiner_onnx,
    load_checkpoint,
    load_refiner,
    save_checkpoint,
)
from icarus_vision.gate_detect.cnn.data import load_split
from icarus_vision.gate_detect.cnn.decode import DecodeConfig
from icarus_vision.gate_detect.cnn.model import CornerNet
from icarus_vision.gate_detect.cnn.rectify import (
    squareness,
    usable,
)
from icarus_vision.gate_detect.cnn.refine import (
    RefineConfig,
    RefineNet,
    Verdicts,
    geometry,
    keep_square,
    refine,
    select,
    skews,
    snap_to_peaks,
    verdicts,
)
from icarus_vision.gate_detect.metrics import mean_sides

from .conftest import QUAD, TINY_MODEL, facing_box, gate_image

CFG = RefineConfig(patch=40, margin=8)


def test_the_squareness_inputs_widen_the_refiners_input():
    cfg = RefineConfig(patch=40, margin=8, square_hfov_deg=95.0)
    assert RefineConfig().num_geom == 11 and cfg.num_geom == 13
    net = RefineNet(cfg).eval()
    quads = np.stack([QUAD, QUAD + 20.0])
    geom = geometry(quads, np.full((2, 3), 0.5, np.float32), (320, 240), cfg)
    np.testing.assert_allclose(geom[:, 11:], squareness(quads, (320, 240), 95.0), atol=1e-6)
    with torch.no_grad():
        assert net(torch.rand(2, 3, 40, 40), torch.from_numpy(geom)).shape == (2, 9)
    assert RefineConfig.from_dict(cfg.to_dict()) == cfg


def test_label_matches_near_candidates_only():
    truth = np.array([QUAD, QUAD + 150.0])
    near, far = QUAD + 4.0, QUAD + 70.0
    t = rt.label(np.array([near, far]), truth)
    np.testing.assert_array_equal(t[0], QUAD)
    assert np.isnan(t[1]).all()


def test_snap_moves_a_corner_to_a_close_peak_of_its_type_only():
    peaks = [(np.array([[101.0, 61.0]]), np.array([0.9]))] + [
        (np.array([[100.0, 60.0]]), np.array([0.8]))
    ] + [(np.zeros((0, 2)), np.zeros(0))] * 2  # fmt: skip
    out, s = snap_to_peaks(QUAD[None], peaks, RefineConfig(snap=0.05))
    np.testing.assert_array_equal(out[0, 0], [101.0, 61.0])  # TL: within 5 % of the side
    np.testing.assert_array_equal(out[0, 1], QUAD[1])  # TR's peak is far away
    assert s[0].tolist() == [0.9, 0.0, 0.0, 0.0]


def test_a_few_training_steps_lower_the_loss():
    """Jittered gates (to correct) and random quads (no gate) of one drawn image."""
    rng = np.random.default_rng(0)
    img = gate_image()[None]
    n = 64
    q = QUAD + rng.normal(size=(n, 4, 2)) * 6.0
    # squares of 30 px somewhere on the grey background, above the gate
    neg = np.array([[0, 0], [30, 0], [30, 30], [0, 30]]) + rng.uniform([0, 0], [280, 15], (n, 1, 2))
    quads = np.concatenate([q, neg])
    targets = np.concatenate([np.repeat(QUAD[None], n, 0), np.full((n, 4, 2), np.nan)])
    scores = np.full((2 * n, 3), 0.5, np.float32)
    x, geom, lab, off, w = rt.make_batch(img, np.zeros(2 * n, int), quads, targets,
                                      scores, CFG, None)  # fmt: skip
    torch.manual_seed(0)
    net = RefineNet(CFG)
    opt = torch.optim.Adam(net.parameters(), 3e-3)
    real = torch.ones(2 * n, dtype=torch.bool)
    losses = []
    for _ in range(30):
        loss = rt.loss_terms(net(x, geom), lab, off, real, w)["loss"]
        opt.zero_grad()
        loss.backward()
        opt.step()
        losses.append(float(loss.detach()))
    assert losses[-1] < 0.5 * losses[0]


def _refiner(seed: int = 0) -> RefineNet:
    torch.manual_seed(seed)
    net = RefineNet(CFG).eval()
    with torch.no_grad():  # a refiner that believes in every candidate
        net.out.bias[0] = 5.0
    return net


def test_refine_reports_corrected_gates_best_first_without_duplicates():
    img = gate_image()
    cands = [(QUAD, np.ones(4), 0.9), (QUAD + 1.0, np.ones(4), 0.8)]
    peaks = [(np.zeros((0, 2)), np.zeros(0))] * 4
    found = refine(_refiner(), img, cands, peaks, CFG)
    assert len(found) == 1  # the second overlaps the first
    corners, cs, p = found[0]
    assert corners.shape == (4, 2) and cs.shape == (4,) and 0.5 < p <= 1.0
    assert refine(_refiner(), img, [], peaks, CFG) == []


def test_mirrored_reading_is_mirror_symmetric():
    # Reading an image and its mirror image with the mirrored reading averaged in gives mirrored
    # answers: the two readings of one are the two readings of the other, swapped.
    img = gate_image()
    w = img.shape[1]
    cand = QUAD + np.array([[2.0, 1.0], [-1.0, 3.0], [0.0, -2.0], [1.5, 0.5]])
    mirrored = cand[FLIP_ORDER] * [-1.0, 1.0] + [w - 1.0, 0.0]
    net, cfg = _refiner(5), RefineConfig(patch=40, margin=8, mirror=True)
    a = verdicts(net, img, [(cand, np.ones(4), 0.9)], cfg)
    b = verdicts(net, np.ascontiguousarray(img[:, ::-1]), [(mirrored, np.ones(4), 0.9)], cfg)
    np.testing.assert_allclose(b.prob, a.prob, atol=1e-4)
    back = b.corners[0][FLIP_ORDER] * [-1.0, 1.0] + [w - 1.0, 0.0]
    np.testing.assert_allclose(back, a.corners[0], atol=0.05)
    # without it, the answers differ (the untrained network is not symmetric)
    plain = RefineConfig(patch=40, margin=8)
    c = verdicts(net, img, [(cand, np.ones(4), 0.9)], plain)
    d = verdicts(net, np.ascontiguousarray(img[:, ::-1]), [(mirrored, np.ones(4), 0.9)], plain)
    d_back = d.corners[0][FLIP_ORDER] * [-1.0, 1.0] + [w - 1.0, 0.0]
    assert np.abs(d_back - c.corners[0]).max() > 0.05
    # the plain reading of the mirror image is the mirrored reading: the result is their mean
    np.testing.assert_allclose(a.corners[0], 0.5 * (c.corners[0] + d_back), atol=0.05)
    logit = 0.5 * (np.log(c.prob / (1 - c.prob)) + np.log(d.prob / (1 - d.prob)))
    np.testing.assert_allclose(a.prob, 1 / (1 + np.exp(-logit)), atol=1e-4)


def test_a_second_pass_reads_again_where_the_first_put_the_corners():
    img, net = gate_image(), _refiner(5)
    cand = QUAD + np.array([[4.0, 2.0], [-3.0, 3.0], [0.0, -4.0], [2.5, 0.5]])
    once = verdicts(net, img, [(cand, np.ones(4), 0.9)], CFG)
    twice = verdicts(net, img, [(cand, np.ones(4), 0.9)], replace(CFG, passes=2))
    again = verdicts(net, img, [(once.corners[0], np.ones(4), 0.9)], CFG)
    np.testing.assert_allclose(twice.prob, again.prob, atol=1e-6)
    np.testing.assert_allclose(twice.corners, again.corners, atol=1e-6)
    assert np.abs(twice.corners - once.corners).max() > 0.05
    for bad in ({"passes": 0}, {"candidate_iou": 0.0}, {"reread_min_px": -1.0}):
        with pytest.raises(ValueError, match="passes must be >= 1, candidate_iou in"):
            RefineNet(replace(CFG, **bad))


class _Counting:
    """A refiner that counts the patches it reads."""

    def __init__(self, net) -> None:
        self.net, self.patches = net, 0

    def __call__(self, x, geom):
        self.patches += len(x)
        return self.net(x, geom)


def test_a_candidate_the_last_pass_barely_moved_is_not_read_again():
    img, net = gate_image(), _refiner(5)
    far = QUAD + np.array([[4.0, 2.0], [-3.0, 3.0], [0.0, -4.0], [2.5, 0.5]])
    gates = [(far, np.ones(4), 0.9), (QUAD + 1.0, np.ones(4), 0.8)]
    once = verdicts(net, img, gates, CFG)
    quads = np.stack([far, QUAD + 1.0])
    shift = np.abs(once.corners - quads).max(axis=(1, 2)) * CFG.side / mean_sides(quads)
    assert shift.min() > 0.0 and shift[0] != shift[1]
    counted = _Counting(net)
    always = verdicts(counted, img, gates, replace(CFG, passes=2))
    assert counted.patches == 4
    for limit, patches in ((0.5 * shift.min(), 4), (shift.mean(), 3), (2.0 * shift.max(), 2)):
        counted.patches = 0
        got = verdicts(counted, img, gates, replace(CFG, passes=2, reread_min_px=limit))
        assert counted.patches == patches
        reread = shift >= limit  # the second pass's answer for these, the first's for the rest
        expected = np.where(reread[:, None, None], always.corners, once.corners)
        np.testing.assert_allclose(got.corners, expected, atol=1e-4)  # (batches of other sizes)
        np.testing.assert_allclose(got.prob, np.where(reread, always.prob, once.prob), atol=1e-6)


def test_candidates_overlap_more_than_the_detectors_output():
    torch.manual_seed(0)
    refiner = RefineNet(RefineConfig(patch=16, margin=4, candidate_iou=0.9))
    det = CnnDetector(CornerNet(TINY_MODEL), DecodeConfig(nms_iou=0.4), refiner=refiner,
                      backend="torch")  # fmt: skip
    assert det.decode_cfg.nms_iou == 0.9 and det.nms_iou == 0.4
    assert CnnDetector(CornerNet(TINY_MODEL), DecodeConfig(nms_iou=0.4)).decode_cfg.nms_iou == 0.4


def test_refiner_files_from_before_the_new_settings_read_as_they_did():
    old = {"patch": 48, "margin": 8, "widths": [16, 32, 64], "hidden": 64, "threshold": 0.3}
    cfg = RefineConfig.from_dict(old)
    assert (cfg.passes, cfg.candidate_iou, cfg.max_skew) == (1, 0.5, 0.0)
    assert RefineConfig.from_dict(RefineConfig().to_dict()) == RefineConfig()


def test_first_stage_reads_the_input_size_and_reports_camera_pixels():
    seen = []

    def net(x: torch.Tensor) -> torch.Tensor:  # one gate centre in the middle cell, stride 4
        seen.append(tuple(x.shape[-2:]))
        out = torch.full((len(x), 15, x.shape[-2] // 4, x.shape[-1] // 4), -9.0)
        out[:, 0, out.shape[-2] // 2, out.shape[-1] // 2] = 9.0
        out[:, 7:] = torch.tensor([-1, -1, 1, -1, 1, 1, -1, 1.0])[:, None, None]  # 16 cells wide
        return out

    images = np.zeros((2, 240, 320, 3), np.uint8)
    cfg = DecodeConfig(nested=False)
    for size in ((320, 240), (256, 192)):
        (gates, _), _ = rt.first_stage(net, images, cfg, input_size=size)
        assert seen[-1] == size[::-1]
        corners = gates[0][0]
        np.testing.assert_allclose(corners.mean(axis=0), [159.5, 119.5])
        np.testing.assert_allclose(mean_sides(corners), 16 * 320 / size[0] * 4, rtol=1e-6)


def test_tune_chooses_the_input_size_mirroring_and_passes(tiny_dataset):
    split = load_split(tiny_dataset, "val", (160, 120))
    torch.manual_seed(0)
    first = CornerNet(TINY_MODEL).eval()
    sizes = rt.input_sizes((160, 120))
    assert sizes == [(160, 120), (128, 96)]
    per_size = {s: rt.first_stage(first, split.images, rt.CANDIDATES, input_size=s) for s in sizes}
    cfg, size, metrics = rt.tune(_refiner(), split, per_size, CFG)
    assert size in sizes and cfg.passes in rt.PASSES and cfg.threshold in rt.THRESHOLDS
    assert {"precision", "recall", "pck", "detections"} <= metrics.keys()


def test_select_keeps_scores_over_the_threshold_best_first_without_overlaps():
    q = np.stack([QUAD, QUAD + 1.0, QUAD + 150.0, QUAD - 90.0])
    v = Verdicts(prob=np.array([0.9, 0.95, 0.8, 0.2]), stage=np.array([0.5, 0.9, 1.0, 1.0]),
                 corners=q)  # fmt: skip
    peaks = [(np.zeros((0, 2)), np.zeros(0))] * 4
    found = select(v, peaks, RefineConfig(threshold=0.3))
    # scores 0.45, 0.855, 0.8, 0.2: the last is under the threshold, the first overlaps the second
    assert [round(f[2], 3) for f in found] == [0.855, 0.8]
    np.testing.assert_array_equal(found[0][0], QUAD + 1.0)
    assert select(Verdicts.empty(), peaks, RefineConfig()) == []


def test_select_drops_big_openings_that_are_not_square_when_asked():
    # 1:1, 1.6:1, small 1.6:1
    q = np.stack([facing_box(48, 48, 60), facing_box(64, 40, 250), facing_box(24, 15, 160)])
    skew = np.abs(squareness(q, (320, 240), 95.0)[:, 0])
    assert skew[0] < 0.05 and skew[1] > 0.4
    v = Verdicts(np.full(3, 0.9), np.ones(3), q, skew)
    peaks = [(np.zeros((0, 2)), np.zeros(0))] * 4
    checked = select(v, peaks, RefineConfig(max_skew=0.4, skew_min_px=30.0))
    assert [f[0][0, 0] for f in checked] == [36.0, 148.0]  # the big rectangle is dropped
    assert len(select(v, peaks, RefineConfig())) == 3
    img = gate_image()  # verdicts measure it
    got = verdicts(_refiner(), img, [(QUAD, np.ones(4), 0.9)], CFG)
    np.testing.assert_allclose(got.skew, np.abs(squareness(got.corners, (320, 240), 95.0)[:, 0]))


def test_verdicts_skip_candidates_under_the_floor():
    img, net = gate_image(), _refiner()
    cands = [(QUAD, np.ones(4), 0.9), (QUAD + 100.0, np.ones(4), 0.1)]
    assert len(verdicts(net, img, cands, CFG).prob) == 1  # floor: CFG.threshold
    assert len(verdicts(net, img, cands, CFG, floor=0.05).prob) == 2


def test_save_load_frozen_and_onnx_give_the_same_output(tmp_path):
    onnx = pytest.importorskip("onnx")
    from onnx.reference import ReferenceEvaluator

    net = _refiner(3)
    torch.manual_seed(1)
    corner = CornerNet(TINY_MODEL).eval()
    save_checkpoint(tmp_path / "ck", corner, DecodeConfig(), {}, net, {"note": "r"})
    _, _, meta = load_checkpoint(tmp_path / "ck")
    loaded = load_refiner(tmp_path / "ck", meta)
    assert loaded.cfg == CFG and meta["refine_training"]["note"] == "r"
    x, g = torch.rand(3, 3, 40, 40), torch.rand(3, CFG.num_geom)
    with torch.no_grad():
        a = net(x, g)
        assert torch.equal(a, loaded(x, g))
    export_refiner_onnx(loaded, tmp_path / "r.onnx")
    sess = ReferenceEvaluator(onnx.load(str(tmp_path / "r.onnx")))
    y = sess.run(None, {"patches": x.numpy(), "geometry": g.numpy()})[0]
    np.testing.assert_allclose(y, a.numpy(), atol=1e-4)
    img = gate_image()
    # frozen (batch norm folded, traced), eager and ONNX Runtime refiners agree in float32 on the
    # same candidates (whole-detector decisions on an untrained map's flat peaks are too close
    # to call across instruction sets)
    settings = [{"frozen": True, "backend": "torch", "bf16": False},
                {"frozen": False, "backend": "torch", "bf16": False}, {"backend": "onnxruntime"}]  # fmt: skip
    dets = [CnnDetector(corner, DecodeConfig(), refiner=loaded, **kw) for kw in settings]
    assert isinstance(dets[2].refiner, OnnxRuntimeNet) and isinstance(dets[2].model, OnnxRuntimeNet)
    quads = [QUAD + shift for shift in (0.0, 30.0, -20.0)]
    cands = [(q, np.ones(4), 0.9) for q in quads]
    a, *others = (verdicts(d.refiner, img, cands, CFG, floor=0.0) for d in dets)
    assert len(a.prob) == 3 and np.abs(a.corners - quads).max() > 0.01  # untrained: moves them
    for b in others:
        np.testing.assert_allclose(b.prob, a.prob, atol=1e-4)
        np.testing.assert_allclose(b.corners, a.corners, atol=1e-3)


def test_missing_or_corrupt_refiner_names_the_file(tmp_path):
    save_checkpoint(tmp_path / "ck", CornerNet(TINY_MODEL), DecodeConfig(), {}, _refiner())
    (tmp_path / "ck" / "refiner.safetensors").write_bytes(b"garbage")
    with pytest.raises(ValueError, match="refiner.safetensors"):
        make_detector(f"cnn:{tmp_path / 'ck'}")
    (tmp_path / "ck" / "refiner.safetensors").unlink()
    with pytest.raises(FileNotFoundError, match="refiner.safetensors"):
        make_detector(f"cnn:{tmp_path / 'ck'}")


def _first_stage(tmp_path):
    torch.manual_seed(0)
    return save_checkpoint(tmp_path / "first", CornerNet(TINY_MODEL).eval(), DecodeConfig())


def test_train_refiner_saves_on_ctrl_c_and_resumes_exactly(tiny_dataset, tmp_path, monkeypatch):
    from safetensors.torch import load_file

    first = _first_stage(tmp_path)
    cfg = rt.RefineTrainConfig(batch_size=16, tune=False)
    kw = {"refine_config": RefineConfig(patch=16, margin=4), "progress": False}

    def interrupt(line: str) -> None:
        if line.startswith("epoch"):
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        rt.train_refiner(first, tiny_dataset, tmp_path / "a", epochs=2, config=cfg,
                         log=interrupt, **kw)  # fmt: skip
    with pytest.raises(ValueError, match="--resume"):
        rt.train_refiner(first, tiny_dataset, tmp_path / "a", epochs=2, config=cfg, **kw)
    # the resumed run reads the training candidates it saved; only the val split's are found
    collected, collect = [], rt.collect
    monkeypatch.setattr(rt, "collect", lambda *a, **k: collected.append(a[1]) or collect(*a, **k))
    rt.train_refiner(first, tiny_dataset, tmp_path / "a", epochs=2, resume=True, progress=False)
    assert [len(split.files) for split in collected] == [4]  # the val split
    rt.train_refiner(first, tiny_dataset, tmp_path / "b", epochs=2, config=cfg, **kw)
    for kept in ("last", "best"):
        a, b = (load_file(tmp_path / r / kept / "refiner.safetensors") for r in "ab")
        assert a.keys() == b.keys() and all(torch.equal(a[k], b[k]) for k in a)
    meta = json.loads((tmp_path / "a" / "best" / "detector.json").read_text())
    assert meta["refine"]["patch"] == 16 and meta["refine_training"]["config"]["batch_size"] == 16
    assert (tmp_path / "a" / "refiner.onnx").is_file()
    assert [h["epoch"] for h in json.loads((tmp_path / "a" / "history.json").read_text())] == [1, 2]
    det = make_detector(f"cnn:{tmp_path / 'a' / 'best'}")
    assert det.refiner is not None
    assert isinstance(det.detect(np.zeros((120, 160, 3), np.uint8)), list)


def test_a_new_run_can_start_from_a_checkpoints_refiner(tiny_dataset, tmp_path):
    from safetensors.torch import load_file

    first = _first_stage(tmp_path)
    init = save_checkpoint(
        tmp_path / "init", CornerNet(TINY_MODEL), DecodeConfig(), {}, _refiner(4)
    )
    cfg = rt.RefineTrainConfig(batch_size=16, tune=False, lr=0.0)  # lr 0: the weights stay
    rt.train_refiner(first, tiny_dataset, tmp_path / "a", epochs=1, config=cfg, init=init,
                     progress=False)  # fmt: skip
    a = load_file(tmp_path / "a" / "best" / "refiner.safetensors")
    b = load_file(init / "refiner.safetensors")
    learned = [k for k in a if "running" not in k and "num_batches" not in k]
    assert learned and all(torch.equal(a[k], b[k]) for k in learned)
    meta = json.loads((tmp_path / "a" / "best" / "detector.json").read_text())
    assert meta["refine"]["patch"] == CFG.patch and meta["refine_training"]["init"] == str(init)
    with pytest.raises(ValueError, match="no refiner"):
        rt.train_refiner(first, tiny_dataset, tmp_path / "b", epochs=1, config=cfg, init=first,
                         progress=False)  # fmt: skip


def test_training_images_mapped_from_disk_train_the_same_refiner(tiny_dataset, tmp_path):
    from safetensors.torch import load_file

    first = _first_stage(tmp_path)
    kw = {"refine_config": RefineConfig(patch=16, margin=4), "progress": False, "epochs": 1}
    cfg = rt.RefineTrainConfig(batch_size=16, tune=False)
    rt.train_refiner(first, tiny_dataset, tmp_path / "mem", config=cfg, **kw)
    disk = replace(cfg, images_on_disk=True)
    rt.train_refiner(first, tiny_dataset, tmp_path / "disk", config=disk, **kw)
    assert (tmp_path / "disk" / rt.TRAIN_IMAGES).is_file()
    assert not (tmp_path / "mem" / rt.TRAIN_IMAGES).exists()
    a, b = (load_file(tmp_path / r / "last" / "refiner.safetensors") for r in ("mem", "disk"))
    assert a.keys() == b.keys() and all(torch.equal(a[k], b[k]) for k in a)


def test_saved_candidates_are_read_back_only_for_the_same_key(tmp_path):
    cands = rt.Candidates(np.arange(3), np.random.rand(3, 4, 2), np.full((3, 4, 2), np.nan),
                          np.random.rand(3, 3).astype(np.float32), [])  # fmt: skip
    path = tmp_path / "c.npz"
    rt.save_candidates(path, cands, {"data": ["x"], "images": 3})
    back = rt.load_candidates(path, {"images": 3, "data": ["x"]})
    assert back is not None and np.array_equal(back.quads, cands.quads)
    assert np.array_equal(back.targets, cands.targets, equal_nan=True)
    assert rt.load_candidates(path, {"data": ["y"], "images": 3}) is None  # other data
    path.write_bytes(b"garbage")
    assert rt.load_candidates(path, {"data": ["x"], "images": 3}) is None
    assert rt.load_candidates(tmp_path / "missing.npz", {}) is None


def test_jittered_truth_and_candidates_of_a_split(tiny_dataset):
    split = load_split(tiny_dataset, "train", (160, 120))
    idx, q, t = rt.jittered_truth(split, np.random.default_rng(0), min_side_px=4.0)
    assert len(idx) == len(q) == len(t) > 0 and usable(q).all()
    # each jittered gate stays near (MATCH) the gate it came from, in its image
    d = np.linalg.norm(q - t, axis=-1).mean(axis=1) / mean_sides(t)
    assert np.median(d) < rt.MATCH


def test_a_finished_run_resumed_is_only_tuned_again(tiny_dataset, tmp_path, monkeypatch):
    first = _first_stage(tmp_path)
    kw = {"refine_config": RefineConfig(patch=16, margin=4), "progress": False}
    cfg = rt.RefineTrainConfig(batch_size=16)  # tuned at the end
    rt.train_refiner(first, tiny_dataset, tmp_path / "a", epochs=1, config=cfg, **kw)
    best = tmp_path / "a" / "best"
    weights = (best / "refiner.safetensors").read_bytes()
    meta = json.loads((best / "detector.json").read_text())
    assert tuple(meta["model"]["input_size"]) in rt.input_sizes((160, 120))
    assert meta["refine"]["passes"] in rt.PASSES and meta["refine"]["max_skew"] in rt.SKEWS
    read = []
    collect = rt.collect
    monkeypatch.setattr(rt, "collect", lambda m, split, *a: read.append(split) or collect(m, split))
    rt.train_refiner(first, tiny_dataset, tmp_path / "a", epochs=1, resume=True, progress=False)
    assert read == []  # no split's candidates collected: tuning reads val itself
    assert (best / "refiner.safetensors").read_bytes() == weights
    assert json.loads((best / "detector.json").read_text())["refine"] == meta["refine"]
    # tuned again on a bigger val set (the val split twice: twice the gates)
    rt.train_refiner(first, tiny_dataset, tmp_path / "a", epochs=1, resume=True, progress=False,
                     val_data=[tiny_dataset, tiny_dataset])  # fmt: skip
    again = json.loads((best / "detector.json").read_text())["refine_training"]
    assert again["val_data"] == [str(tiny_dataset)] * 2
    assert again["val"]["gates"] == 2 * meta["refine_training"]["val"]["gates"] > 0
    assert (best / "refiner.safetensors").read_bytes() == weights


def test_training_candidates_read_at_the_detectors_input(tiny_dataset, tmp_path, monkeypatch):
    first = _first_stage(tmp_path)
    kw = {"refine_config": RefineConfig(patch=16, margin=4), "progress": False}
    seen = []
    collect = rt.collect
    monkeypatch.setattr(
        rt,
        "collect",
        lambda m, split, c, at: seen.append((c.nms_iou, at)) or collect(m, split, c, at),
    )
    cfg = rt.RefineTrainConfig(batch_size=16, tune=False, candidate_scale=0.8, candidate_iou=0.85)
    rt.train_refiner(first, tiny_dataset, tmp_path / "a", epochs=1, config=cfg, **kw)
    assert seen == [(0.85, (128, 96))] * 2  # train and val, 0.8 of the 160x120 camera
    meta = json.loads((tmp_path / "a" / "best" / "detector.json").read_text())
    assert meta["refine_training"]["config"]["candidate_scale"] == 0.8
    seen.clear()
    rt.train_refiner(
        first,
        tiny_dataset,
        tmp_path / "b",
        epochs=1,
        config=replace(cfg, candidate_scale=1.0, candidate_iou=0.5),
        **kw,
    )
    assert seen == [(0.5, None)] * 2  # the default: camera frames as they are
    with pytest.raises(ValueError, match="candidate_scale"):
        rt.train_refiner(
            first,
            tiny_dataset,
            tmp_path / "c",
            epochs=1,
            config=replace(cfg, candidate_scale=0.0),
            **kw,
        )


def test_a_new_run_reads_candidates_of_the_same_key_left_in_its_folder(
    tiny_dataset, tmp_path, monkeypatch
):
    import shutil

    first = _first_stage(tmp_path)
    kw = {"epochs": 1, "config": rt.RefineTrainConfig(batch_size=16, tune=False),
          "refine_config": RefineConfig(patch=16, margin=4), "progress": False}  # fmt: skip
    rt.train_refiner(first, tiny_dataset, tmp_path / "a", **kw)
    (tmp_path / "b").mkdir()
    shutil.copy(tmp_path / "a" / rt.CANDIDATE_CACHE, tmp_path / "b" / rt.CANDIDATE_CACHE)
    collected, collect = [], rt.collect
    monkeypatch.setattr(rt, "collect", lambda *a, **k: collected.append(a[1]) or collect(*a, **k))
    # another refiner (wider context) on the same data and corner network
    rt.train_refiner(
        first,
        tiny_dataset,
        tmp_path / "b",
        **{**kw, "refine_config": RefineConfig(patch=16, margin=3)},
    )
    assert [len(split.files) for split in collected] == [4]  # the val split only
    # another corner network: collected again
    torch.manual_seed(1)
    other = save_checkpoint(tmp_path / "other", CornerNet(TINY_MODEL).eval(), DecodeConfig())
    (tmp_path / "d").mkdir()
    shutil.copy(tmp_path / "a" / rt.CANDIDATE_CACHE, tmp_path / "d" / rt.CANDIDATE_CACHE)
    collected.clear()
    rt.train_refiner(other, tiny_dataset, tmp_path / "d", **kw)
    assert [len(split.files) for split in collected] == [8, 4]  # train and val


def test_a_dataset_generated_again_has_another_digest(tmp_path):
    from icarus_vision.gate_detect.cnn.stage_train import dataset_digest

    assert dataset_digest(tmp_path) == "none"
    (tmp_path / "manifest.json").write_text('{"seed": 1}')
    one = dataset_digest(tmp_path)
    (tmp_path / "manifest.json").write_text('{"seed": 2}')
    assert len(one) == 64 and dataset_digest(tmp_path) != one


def test_keep_square_checks_the_corners_it_is_given():
    found = [(facing_box(48, 48, 60), np.ones(4), 0.9), (facing_box(64, 40, 250), np.ones(4), 0.8),
             (facing_box(24, 15, 160), np.ones(4), 0.7)]  # fmt: skip
    kept = keep_square(found, (320, 240), RefineConfig(max_skew=0.4, skew_min_px=30.0))
    assert [f[2] for f in kept] == [0.9, 0.7]  # the big 1.6:1 opening is dropped
    assert keep_square(found, (320, 240), RefineConfig()) == found  # no check
    assert keep_square([], (320, 240), RefineConfig(max_skew=0.4)) == []


def test_a_small_gate_out_of_square_needs_a_high_score():
    # 1.6:1 openings of 26 px (in 20-30 px) and 19.5 px (under 20 px) mean side
    small, tiny = facing_box(32, 20, 100), facing_box(24, 15, 200)
    cfg = RefineConfig(max_skew=0.4, skew_min_px=30.0, small_skew_score=0.5, small_skew_min_px=20.0)
    found = [(small, np.ones(4), 0.7), (small + 40.0, np.ones(4), 0.3), (tiny, np.ones(4), 0.3)]
    kept = keep_square(found, (320, 240), cfg)
    assert [f[2] for f in kept] == [0.7, 0.3] and kept[1][0] is tiny  # the weak 26 px one dropped
    assert keep_square(found, (320, 240), replace(cfg, small_skew_score=0.0)) == found
    square = facing_box(26, 26, 100)  # square enough: kept however weak
    assert len(keep_square([(square, np.ones(4), 0.3)], (320, 240), cfg)) == 1
    v = Verdicts(np.array([0.7, 0.3, 0.3]), np.ones(3), np.stack([f[0] for f in found]),
                 skews(np.stack([f[0] for f in found]), (320, 240)))  # fmt: skip
    peaks = [(np.zeros((0, 2)), np.zeros(0))] * 4
    assert [f[2] for f in select(v, peaks, replace(cfg, threshold=0.2))] == [0.7, 0.3]


def test_the_detector_reports_the_refiners_gates_in_the_frame_only(monkeypatch):
    import icarus_vision.gate_detect.cnn as cnn

    inside, cut = facing_box(40, 40, 100), facing_box(40, 40, 5)  # the second 15 px off the left
    monkeypatch.setattr(
        cnn, "refine", lambda *a: [(cut, np.ones(4), 0.9), (inside, np.ones(4), 0.8)]
    )
    det = CnnDetector(CornerNet(TINY_MODEL), refiner=_refiner(), backend="torch")
    assert [d.score for d in det.detect(gate_image())] == [0.8]
    det = CnnDetector(CornerNet(TINY_MODEL), DecodeConfig(max_outside_px=None), refiner=_refiner(),
                      backend="torch")  # fmt: skip
    assert [d.score for d in det.detect(gate_image())] == [0.9, 0.8]
