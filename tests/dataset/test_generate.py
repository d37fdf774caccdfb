"""generate_dataset: determinism, resuming, corrupt shards, refusing another dataset, bad input."""

from __future__ import annotations

import json
import shutil

import pytest

from icarus_vision.dataset import generate_dataset
from icarus_vision.dataset.layout import plan_shards, shard_path
from icarus_vision.dataset.shard import read_valid_shard
from icarus_vision.render import egl
from icarus_vision.render.recipe import load_recipe

from .conftest import TINY_IMAGES, files_of, write_recipe

SHARDS = ("train-0000", "train-0001", "val-0000", "test-0000")


def test_reference_layout(reference):
    out, result = reference
    assert result.generated == SHARDS and result.reused == ()
    names = set(files_of(out))
    assert {f"images/{i:06d}.png" for i in range(1, TINY_IMAGES + 1)} <= names
    for f in ("manifest.json", "config.json", "contact_sheet.png", "annotations/train.json"):
        assert f in names
    assert not [n for n in names if n.endswith(".tmp")]
    # one entry per worker that rendered a shard: on a busy machine one of the two may take all four
    peaks = result.worker_peak_rss_mb
    assert 1 <= len(peaks) <= 2 and all(m > 10 for m in peaks)


def test_same_recipe_and_seed_give_byte_identical_files(reference, tiny_recipe, tmp_path):
    ref, _ = reference
    again = generate_dataset(tiny_recipe, tmp_path / "again", TINY_IMAGES, workers=2, seed=3)
    assert files_of(again.out_dir) == files_of(ref)
    # The shards' own random streams make the output independent of the worker count too.
    serial = generate_dataset(tiny_recipe, tmp_path / "serial", TINY_IMAGES, workers=1, seed=3)
    assert files_of(serial.out_dir) == files_of(ref)


@pytest.mark.slow
def test_ray_tasks_write_the_same_bytes_and_resume(ray_here, reference, tiny_recipe, tmp_path):
    ref, _ = reference
    out = tmp_path / "ray"
    with pytest.raises(KeyboardInterrupt):  # Ctrl-C once two shards are written
        generate_dataset(tiny_recipe, out, TINY_IMAGES, seed=3, ray=True,
                         progress=_interrupt_after(8))  # fmt: skip
    _assert_nothing_looks_complete(out, tiny_recipe)
    result = generate_dataset(tiny_recipe, out, TINY_IMAGES, seed=3, ray=True)
    assert len(result.reused) >= 2 and set(result.reused) | set(result.generated) == set(SHARDS)
    assert files_of(out) == files_of(ref)
    damaged = out / "images/000005.png"  # a damaged shard is rendered again, alone
    damaged.write_bytes(damaged.read_bytes()[:100])
    result = generate_dataset(tiny_recipe, out, TINY_IMAGES, seed=3, ray=True)
    assert result.generated == ("train-0001",)
    assert files_of(out) == files_of(ref)


def test_another_seed_gives_other_images(tiny_recipe, tmp_path):
    a = generate_dataset(tiny_recipe, tmp_path / "a", 4, workers=1, seed=0)
    b = generate_dataset(tiny_recipe, tmp_path / "b", 4, workers=1, seed=1)
    assert (a.out_dir / "images/000001.png").read_bytes() != (
        b.out_dir / "images/000001.png"
    ).read_bytes()


def _interrupt_after(n: int):
    def progress(done: int, total: int) -> None:
        if done >= n:
            raise KeyboardInterrupt

    return progress


def _assert_nothing_looks_complete(out, recipe_path):
    """After an interruption: no manifest, and every shard record present is intact."""
    assert not (out / "manifest.json").exists()
    for spec in plan_shards(TINY_IMAGES, load_recipe(recipe_path).dataset):
        if shard_path(out, spec).exists():
            assert read_valid_shard(out, spec) is not None


def test_resume_after_interrupt_in_process(reference, tiny_recipe, tmp_path):
    out = tmp_path / "ds"
    with pytest.raises(KeyboardInterrupt):  # Ctrl-C while the 9th image is written
        generate_dataset(
            tiny_recipe, out, TINY_IMAGES, workers=1, seed=3, progress=_interrupt_after(9)
        )
    _assert_nothing_looks_complete(out, tiny_recipe)
    result = generate_dataset(tiny_recipe, out, TINY_IMAGES, workers=2, seed=3)
    assert result.reused == SHARDS[:2] and result.generated == SHARDS[2:]
    assert files_of(out) == files_of(reference[0])


def test_resume_after_interrupt_of_worker_processes(reference, tiny_recipe, tmp_path):
    out = tmp_path / "ds"
    with pytest.raises(KeyboardInterrupt):
        generate_dataset(
            tiny_recipe, out, TINY_IMAGES, workers=2, seed=3, progress=_interrupt_after(1)
        )
    _assert_nothing_looks_complete(out, tiny_recipe)
    result = generate_dataset(tiny_recipe, out, TINY_IMAGES, workers=2, seed=3)
    assert set(result.generated) | set(result.reused) == set(SHARDS)
    assert files_of(out) == files_of(reference[0])


def _truncate_image(out):
    p = out / "images/000006.png"  # in train-0001
    p.write_bytes(p.read_bytes()[:100])


def _delete_image(out):
    (out / "images/000006.png").unlink()


def _garble_record(out):
    p = out / "shards/train-0001.json"
    p.write_bytes(p.read_bytes()[:-40])


def _edit_record(out):
    p = out / "shards/train-0001.json"
    record = json.loads(p.read_text())
    record["images"][0]["body_pos"][0] += 1.0  # the checksum no longer matches
    p.write_text(json.dumps(record))


def _delete_record(out):
    (out / "shards/train-0001.json").unlink()


@pytest.mark.parametrize(
    "damage", [_truncate_image, _delete_image, _garble_record, _edit_record, _delete_record]
)
def test_damaged_shard_is_regenerated_alone(reference, tiny_recipe, tmp_path, damage):
    ref, _ = reference
    out = tmp_path / "ds"
    shutil.copytree(ref, out)
    damage(out)
    result = generate_dataset(tiny_recipe, out, TINY_IMAGES, workers=1, seed=3)
    assert result.generated == ("train-0001",)
    assert files_of(out) == files_of(ref)


def test_complete_dataset_is_kept_as_is(reference, tiny_recipe, tmp_path):
    out = tmp_path / "ds"
    shutil.copytree(reference[0], out)
    result = generate_dataset(tiny_recipe, out, TINY_IMAGES, workers=2, seed=3)
    assert result.generated == () and result.reused == SHARDS
    assert files_of(out) == files_of(reference[0])


def test_folder_of_another_dataset_is_refused_unless_forced(reference, tmp_path):
    out = tmp_path / "ds"
    shutil.copytree(reference[0], out)
    other = write_recipe(tmp_path / "other.toml", name="other")
    with pytest.raises(ValueError, match="different dataset.*'gates-v1'.*--force"):
        generate_dataset(other, out, TINY_IMAGES, workers=1, seed=3)
    with pytest.raises(ValueError, match="different dataset.*seed 3"):
        generate_dataset(write_recipe(tmp_path / "same.toml"), out, TINY_IMAGES, workers=1, seed=4)
    result = generate_dataset(other, out, 4, workers=1, seed=3, force=True)
    assert result.manifest["name"] == "other" and result.manifest["num_images"] == 4
    assert sorted(p.name for p in (out / "images").iterdir()) == [
        f"{i:06d}.png" for i in range(1, 5)
    ]
    assert len(list((out / "shards").iterdir())) == len(result.generated)


def test_non_empty_foreign_folder_is_refused(tiny_recipe, tmp_path):
    (tmp_path / "notes.txt").write_text("mine")
    with pytest.raises(ValueError, match="not empty"):
        generate_dataset(tiny_recipe, tmp_path, 4, workers=1)
    generate_dataset(tiny_recipe, tmp_path, 2, workers=1, force=True)
    assert (tmp_path / "notes.txt").read_text() == "mine"  # force removes only dataset files


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"num_images": 0}, "num_images must be an integer >= 1"),
        ({"workers": 0}, "workers must be an integer >= 1"),
        ({"seed": -1}, "seed must be an integer >= 0"),
    ],
)
def test_bad_numbers_are_refused(tiny_recipe, tmp_path, kwargs, match):
    args = {"num_images": 4, "workers": 1, "seed": 0, **kwargs}
    with pytest.raises(ValueError, match=match):
        generate_dataset(tiny_recipe, tmp_path / "ds", **args)
    assert not (tmp_path / "ds").exists()


def test_malformed_recipe_names_the_key(tmp_path):
    bad = write_recipe(tmp_path / "bad.toml", shard_sise=4)
    with pytest.raises(ValueError, match=r"bad\.toml: dataset\.shard_sise: unknown key"):
        generate_dataset(bad, tmp_path / "ds", 4, workers=1)
    with pytest.raises(ValueError, match="recipe file not found"):
        generate_dataset(tmp_path / "missing.toml", tmp_path / "ds", 4, workers=1)


def test_tiny_renderer_is_recorded_and_keeps_the_identity(reference):
    out, result = reference
    assert result.manifest["renderer"] == "tiny"
    assert "renderer" not in json.loads((out / "config.json").read_text())  # as before: resumable


def test_egl_dataset_has_the_same_labels_and_is_never_mixed_with_tiny(
    reference, tiny_recipe, tmp_path
):
    out = tmp_path / "ds"
    try:
        result = generate_dataset(tiny_recipe, out, TINY_IMAGES, workers=1, seed=3, renderer="egl")
    except RuntimeError as e:
        pytest.skip(f"PyBullet's EGL renderer cannot load here: {e}")
    assert result.manifest["renderer"] == "egl"
    assert json.loads((out / "config.json").read_text())["renderer"] == "egl"
    tiny = [json.loads(p.read_text()) for p in sorted((reference[0] / "shards").iterdir())]
    gl = [json.loads(p.read_text()) for p in sorted((out / "shards").iterdir())]
    tiny_anns = [a for r in tiny for a in r["annotations"]]
    gl_anns = [a for r in gl for a in r["annotations"]]
    assert len(gl_anns) == len(tiny_anns) > 0  # same scenes, poses and gates: the same labels
    same_flags = 0
    for a, b in zip(tiny_anns, gl_anns, strict=True):
        assert (a["image_id"], a["corners_px"]) == (b["image_id"], b["corners_px"])
        same_flags += a["keypoints"][2::3] == b["keypoints"][2::3]
    assert same_flags >= 0.9 * len(tiny_anns)
    with pytest.raises(ValueError, match="different dataset.*renderer 'egl'"):
        generate_dataset(tiny_recipe, out, TINY_IMAGES, workers=1, seed=3)
    again = generate_dataset(tiny_recipe, out, TINY_IMAGES, workers=1, seed=3, renderer="egl")
    assert again.generated == () and again.manifest == result.manifest


def test_egl_dataset_fails_where_the_plugin_cannot_load(monkeypatch, tiny_recipe, tmp_path):
    monkeypatch.setattr(egl, "egl_plugin_path", lambda: None)
    with (
        pytest.warns(UserWarning, match="EGL rendering unavailable"),
        pytest.raises(RuntimeError, match="cannot render with 'egl' here"),
    ):
        generate_dataset(tiny_recipe, tmp_path / "ds", 4, workers=1, renderer="egl")
    assert not (tmp_path / "ds" / "manifest.json").exists()
