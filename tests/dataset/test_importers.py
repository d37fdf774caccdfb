"""`import-gates`: AlphaPilot JSON, corners CSV and YOLO-pose labels to a COCO-keypoints folder,
on small files the tests write; `eval-detector` on the result and on a folder of gate-free images."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from icarus_vision.cli import app
from icarus_vision.dataset.importers import order_as_seen
from tests.gate_detect.conftest import QUAD, gate_image

runner = CliRunner()
TL_TR_BR_BL = np.array([[10.0, 20.0], [110.0, 25.0], [105.0, 120.0], [8.0, 115.0]])


@pytest.mark.parametrize("start", range(4))
@pytest.mark.parametrize("reverse", [False, True])
def test_corners_are_put_in_the_order_seen(start, reverse):
    q = np.roll(TL_TR_BR_BL, -start, axis=0)
    q = q[::-1] if reverse else q
    np.testing.assert_array_equal(order_as_seen(q), TL_TR_BR_BL)


def test_a_rolled_gate_keeps_its_top_left_corner_first():
    c = TL_TR_BR_BL.mean(axis=0)
    a = np.radians(30.0)
    rot = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
    rolled = (TL_TR_BR_BL - c) @ rot.T + c
    np.testing.assert_allclose(order_as_seen(np.roll(rolled, 2, axis=0)), rolled)


def _images(folder, names, size=(320, 240)):
    folder.mkdir(parents=True, exist_ok=True)
    frame = cv2.resize(gate_image(), size)
    for n in names:
        cv2.imwrite(str(folder / n), cv2.cvtColor(frame, cv2.COLOR_RGB2BGR))


def _coco(out):
    coco = json.loads((out / "annotations.json").read_text())
    kps = {im["file_name"]: [] for im in coco["images"]}
    names = {im["id"]: im["file_name"] for im in coco["images"]}
    for a in coco["annotations"]:
        kps[names[a["image_id"]]].append(np.asarray(a["keypoints"], float).reshape(4, 3))
    return coco, kps


def test_alphapilot_labels_in_any_corner_order(tmp_path):
    src = tmp_path / "ap"
    _images(src / "images", ["IMG_1.JPG", "IMG_2.JPG", "IMG_3.JPG"])
    start_br = np.roll(QUAD, -2, axis=0).ravel().tolist()
    (src / "labels.json").write_text(json.dumps(
        {"IMG_1.JPG": [QUAD.ravel().tolist()], "IMG_2.JPG": [start_br], "IMG_3.JPG": [[]]}
    ))  # fmt: skip
    r = runner.invoke(app, ["import-gates", str(src), "--format", "alphapilot",
                            "--out", str(tmp_path / "out")])  # fmt: skip
    assert r.exit_code == 0, r.output
    assert "3 images (1 without gates), 2 gates" in r.output
    coco, kps = _coco(tmp_path / "out")
    for name in ("IMG_1.JPG", "IMG_2.JPG"):
        (k,) = kps[name]
        np.testing.assert_allclose(k[:, :2], QUAD)
        assert (k[:, 2] == 2).all()
    assert kps["IMG_3.JPG"] == []
    assert coco["categories"][0]["keypoints"] == ["TL", "TR", "BR", "BL"]
    copied = tmp_path / "out" / "images" / "IMG_2.JPG"
    assert copied.read_bytes() == (src / "images" / "IMG_2.JPG").read_bytes()


def test_corners_csv_with_header_and_unlabelled_images(tmp_path):
    src = tmp_path / "cz"
    _images(src / "images", ["a.jpg", "b.jpg", "c.jpg"], size=(315, 160))
    rows = ["filename,x1,y1,x2,y2,x3,y3,x4,y4",
            "a.jpg," + ",".join(f"{v:g}" for v in np.roll(QUAD, -1, axis=0).ravel()),
            "a.jpg," + ",".join(f"{v:g}" for v in (QUAD / 2).ravel()), "b.jpg,1,1,30,1,30,30,1,30"]  # fmt: skip
    (src / "corners.csv").write_text("\n".join(rows) + "\n")
    out = tmp_path / "out"
    r = runner.invoke(app, ["import-gates", str(src / "corners.csv"), "--format", "corners-csv",
                            "--out", str(out), "--unlabelled"])  # fmt: skip
    assert r.exit_code == 0, r.output
    coco, kps = _coco(out)
    assert len(kps["a.jpg"]) == 2 and len(kps["b.jpg"]) == 1 and kps["c.jpg"] == []
    np.testing.assert_allclose(kps["a.jpg"][0][:, :2], QUAD)
    assert {(im["width"], im["height"]) for im in coco["images"]} == {(315, 160)}
    only = tmp_path / "only"
    r = runner.invoke(
        app, ["import-gates", str(src), "--format", "corners-csv", "--out", str(only)]
    )
    assert r.exit_code == 0 and len(_coco(only)[0]["images"]) == 2  # c.jpg has no row


def test_yolo_pose_labels_are_denormalised(tmp_path):
    src = tmp_path / "tii"
    _images(src / "images", ["f1.png", "f2.png"], size=(360, 360))
    (src / "labels").mkdir()
    q = np.roll(QUAD, -3, axis=0) / 360.0
    kp = " ".join(f"{x:.6f} {y:.6f} 2" for x, y in q)
    (src / "labels" / "f1.txt").write_text(f"0 0.4 0.3 0.3 0.3 {kp}\n")
    r = runner.invoke(app, ["import-gates", str(src), "--format", "yolo-pose", "--out",
                            str(tmp_path / "out")])  # fmt: skip
    assert r.exit_code == 0, r.output
    _, kps = _coco(tmp_path / "out")
    np.testing.assert_allclose(kps["f1.png"][0][:, :2], QUAD, atol=1e-3)
    assert kps["f2.png"] == []  # no label file: no gate


@pytest.mark.parametrize(
    "fmt, label, text, needle",
    [
        ("alphapilot", "labels.json", '{"x.jpg": [[1, 2, 3]]}', "needs 8 numbers"),
        ("alphapilot", "labels.json", '{"gone.jpg": [[1, 2, 3, 4, 5, 6, 7, 8]]}', "gone.jpg"),
        ("alphapilot", "labels.json", "[1, 2", "not a readable JSON"),
        ("corners-csv", "c.csv", "x.jpg,1,2,3,4,5,6,7,8\nx.jpg,1,2,a,4,5,6,7,8\n", "line 2"),
        ("corners-csv", "c.csv", "x.jpg,1,2,3\n", "expected filename and 8 coordinates"),
    ],
)
def test_bad_labels_are_one_line_errors(tmp_path, fmt, label, text, needle):
    _images(tmp_path / "images", ["x.jpg"])
    (tmp_path / label).write_text(text)
    r = runner.invoke(app, ["import-gates", str(tmp_path / label), "--format", fmt,
                            "--out", str(tmp_path / "out")])  # fmt: skip
    lines = [s for s in r.output.strip().splitlines() if s.strip()]
    assert r.exit_code == 1 and len(lines) == 1 and needle in lines[0], r.output


def test_import_refuses_a_used_folder_and_an_unknown_format(tmp_path):
    _images(tmp_path / "images", ["x.jpg"])
    (tmp_path / "labels.json").write_text('{"x.jpg": []}')
    (tmp_path / "used").mkdir()
    (tmp_path / "used" / "keep.txt").write_text("mine")
    r = runner.invoke(app, ["import-gates", str(tmp_path), "--format", "alphapilot",
                            "--out", str(tmp_path / "used")])  # fmt: skip
    assert r.exit_code == 1 and "not an empty folder" in r.output
    r = runner.invoke(app, ["import-gates", str(tmp_path), "--format", "coco",
                            "--out", str(tmp_path / "o")])  # fmt: skip
    assert r.exit_code == 1 and "alphapilot, corners-csv, yolo-pose" in r.output


def test_eval_detector_on_a_coco_folder_and_on_gate_free_images(tmp_path):
    """A COCO folder without manifest, camera or distances, of a non-4:3 size; then a folder of
    images alone, where every detection is a false positive."""
    src = tmp_path / "src"
    wide = np.concatenate([gate_image(), np.full((240, 160, 3), 110, np.uint8)], axis=1)
    (src / "images").mkdir(parents=True)
    cv2.imwrite(str(src / "images" / "g.png"), cv2.cvtColor(wide, cv2.COLOR_RGB2BGR))
    (src / "labels.json").write_text(json.dumps({"g.png": [QUAD.ravel().tolist()]}))
    out = tmp_path / "coco"
    assert runner.invoke(app, ["import-gates", str(src), "--format", "alphapilot",
                               "--out", str(out)]).exit_code == 0  # fmt: skip
    report = tmp_path / "r.json"
    r = runner.invoke(app, ["eval-detector", "--data", str(out), "--detector", "opencv",
                            "--json", str(report), "--resamples", "0"])  # fmt: skip
    assert r.exit_code == 0, r.output
    rep = json.loads(report.read_text())
    assert rep["images"] == 1 and rep["gates"] == 1 and rep["has_distance"] is False
    assert rep["recall"] == 1.0 and rep["corner_error_side"]["median"] < 0.05
    assert rep["error_model"] is None and "distance m" not in r.output
    cv2.imwrite(str(tmp_path / "empty.png"), np.full((120, 200, 3), 90, np.uint8))
    negatives = tmp_path / "neg"
    negatives.mkdir()
    cv2.imwrite(str(negatives / "gate.png"), cv2.cvtColor(wide, cv2.COLOR_RGB2BGR))
    cv2.imwrite(str(negatives / "grey.png"), np.full((120, 200, 3), 90, np.uint8))
    r = runner.invoke(app, ["eval-detector", "--data", str(negatives), "--detector", "opencv",
                            "--json", str(report), "--resamples", "0"])  # fmt: skip
    assert r.exit_code == 0, r.output
    rep = json.loads(report.read_text())
    assert rep["images"] == 2 and rep["gates"] == 0 and rep["false_positives"] == 1
    assert rep["precision"] == 0.0 and rep["recall"] is None
