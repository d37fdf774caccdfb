"""Rectifying candidates: homographies, patches, corners between patch and image, squareness."""

from __future__ import annotations

import numpy as np

from icarus_vision.gate_detect.base import FLIP_ORDER
from icarus_vision.gate_detect.cnn.rectify import (
    corners_to_offsets,
    extract,
    homographies,
    network_patches,
    offsets_to_corners,
    patch_to_image,
    square,
    squareness,
    to_tensor,
    transform,
    usable,
)
from icarus_vision.gate_detect.cnn.refine import RefineConfig

from .conftest import QUAD, gate_image

CFG = RefineConfig(patch=40, margin=8)


def test_homography_puts_the_candidate_on_the_square_and_back():
    h = homographies(QUAD[None], CFG)
    np.testing.assert_allclose(corners_to_offsets(h, QUAD[None], CFG), 0.0, atol=1e-9)
    truth = QUAD + np.array([[3.0, -2.0], [0.0, 4.0], [-5.0, 1.0], [2.0, 2.0]])
    off = corners_to_offsets(h, truth[None], CFG)
    np.testing.assert_allclose(offsets_to_corners(h, off, CFG)[0], truth, atol=1e-6)


def test_patch_shows_the_opening_on_the_square_and_the_frame_around_it():
    patch = extract(gate_image(), homographies(QUAD[None], CFG), CFG)[0]
    lo, hi = square(CFG)[0, 0], square(CFG)[2, 0]
    inside = patch[int(lo) + 3 : int(hi) - 2, int(lo) + 3 : int(hi) - 2]
    assert (inside == 110).all()
    mid = CFG.patch // 2
    for y, x in [(int(lo) - 2, mid), (int(hi) + 3, mid), (mid, int(lo) - 2), (mid, int(hi) + 3)]:
        assert tuple(patch[y, x]) == (255, 90, 0), (y, x)


def test_corner_order_swapped_gives_the_mirrored_patch():
    img = np.random.default_rng(0).integers(0, 256, (240, 320, 3), dtype=np.uint8)
    a = extract(img, homographies(QUAD[None], CFG), CFG)[0].astype(int)
    b = extract(img, homographies(QUAD[None][:, FLIP_ORDER], CFG), CFG)[0].astype(int)
    assert np.abs(a[:, ::-1] - b).max() <= 1


def test_squareness_tells_a_square_from_a_rectangle_in_any_view():
    from icarus_vision.render.camera import intrinsics

    k = intrinsics(320, 240, 95.0)
    rng = np.random.default_rng(0)

    def seen(width: float, height: float) -> np.ndarray:
        """Corners of a width x height frame 4 m ahead, turned at random, in the image."""
        local = np.array([[-1, 1, 0], [1, 1, 0], [1, -1, 0], [-1, -1, 0]]) * [
            width / 2,
            height / 2,
            0,
        ]
        out = []
        for _ in range(20):
            yaw, pitch, roll = rng.uniform(-0.9, 0.9), rng.uniform(-0.5, 0.5), rng.uniform(-1, 1)
            rz = np.array(
                [[np.cos(roll), -np.sin(roll), 0], [np.sin(roll), np.cos(roll), 0], [0, 0, 1]]
            )
            ry = np.array(
                [[np.cos(yaw), 0, np.sin(yaw)], [0, 1, 0], [-np.sin(yaw), 0, np.cos(yaw)]]
            )
            rx = np.array(
                [[1, 0, 0], [0, np.cos(pitch), -np.sin(pitch)], [0, np.sin(pitch), np.cos(pitch)]]
            )
            pts = local * [1, -1, 1] @ (rz @ ry @ rx).T + [0.3, -0.2, 4.0]
            uv = pts @ k.T
            out.append(uv[:, :2] / uv[:, 2:])
        return np.array(out)

    sq = squareness(seen(1.0, 1.0), (320, 240), 95.0)
    np.testing.assert_allclose(sq, 0.0, atol=1e-4)  # a square, under the nominal camera
    tall = squareness(seen(1.0, 1.6), (320, 240), 95.0)
    np.testing.assert_allclose(np.abs(tall[:, 0]), np.log(1.6), atol=1e-4)
    np.testing.assert_allclose(tall[:, 1], 0.0, atol=1e-4)
    # under another camera a square is still close to one
    wide = squareness(seen(1.0, 1.0), (320, 240), 105.0)
    assert np.abs(wide).max() < 0.25


def test_usable_refuses_degenerate_candidates():
    bad = [QUAD[[1, 0, 3, 2]], QUAD[[0, 2, 1, 3]], QUAD * 0.01 + 5, np.full((4, 2), np.nan)]
    assert usable(np.array([QUAD, *bad])).tolist() == [True, False, False, False, False]


def test_patch_to_image_inverts_the_homographies():
    quads = np.stack([QUAD, QUAD * 0.5 + (20.0, 10.0)])
    back = patch_to_image(quads, CFG)
    np.testing.assert_allclose(
        back / back[:, 2:, 2:], np.linalg.inv(homographies(quads, CFG)), rtol=1e-6, atol=1e-9
    )
    np.testing.assert_allclose(transform(back, square(CFG)[None].repeat(2, 0)), quads, atol=1e-3)


def test_the_mirrored_reading_is_the_flipped_patch_read_back_through_the_flipped_corners():
    img = np.random.default_rng(1).integers(0, 256, (240, 320, 3), dtype=np.uint8)
    quads = np.stack([QUAD, QUAD * 0.6 + (30.0, 20.0)])
    h = homographies(quads, CFG)
    x = network_patches(extract(img, h, CFG), mirror=True)
    assert x.shape == (4, 3, CFG.patch, CFG.patch) and x.flags.c_contiguous
    np.testing.assert_array_equal(x[2:], x[:2, :, :, ::-1])
    np.testing.assert_allclose(x[:2], to_tensor(extract(img, h, CFG)).numpy(), atol=0)
    # as if the swapped corner order had been warped: within one grey level
    swapped = extract(img, homographies(quads[:, FLIP_ORDER], CFG), CFG)
    assert np.abs(x[2:] * 255.0 - to_tensor(swapped).numpy() * 255.0).max() <= 1.0 + 1e-4
    # corners read from the mirrored patch go back through the swapped corners' homography
    rng = np.random.default_rng(2)
    off, off_m = rng.normal(0.0, 0.05, (2, 2, 8))
    expected = 0.5 * (
        offsets_to_corners(h, off, CFG)
        + offsets_to_corners(homographies(quads[:, FLIP_ORDER], CFG), off_m, CFG)[:, FLIP_ORDER]
    )
    got = offsets_to_corners(h, off, CFG, mirrored=off_m, back=patch_to_image(quads, CFG))
    np.testing.assert_allclose(got, expected, atol=1e-3)
