from __future__ import annotations

import math

import numpy as np
import pytest

from icarus_vision.render.camera import (
    Camera,
    body_to_camera_rotation,
    camera_poses,
    intrinsics,
    project_points,
    unproject_pixels,
    world_to_camera,
)
from icarus_vision.sim.dynamics import rpy_to_quat
from icarus_vision.sim.quad import CameraParams

LEVEL = np.array([0.0, 0.0, 0.0, 1.0])


def test_intrinsics_from_hfov():
    k = intrinsics(320, 240, 90.0)
    assert k[0, 0] == pytest.approx(160.0) and k[1, 1] == pytest.approx(160.0)
    assert (k[0, 2], k[1, 2]) == (159.5, 119.5)


def test_project_matches_analytic_pinhole():
    cam = Camera(uptilt_deg=0.0)
    pts = np.array([[4.0, 0.0, 0.0], [4.0, 1.0, 0.5], [2.0, -0.5, -0.25]])  # body = world here
    px, z = cam.project(pts, np.zeros(3), LEVEL)
    f, cx, cy = 160.0, 159.5, 119.5
    expected = np.stack([cx - f * pts[:, 1] / pts[:, 0], cy - f * pts[:, 2] / pts[:, 0]], axis=1)
    np.testing.assert_allclose(px, expected, atol=1e-9)
    np.testing.assert_allclose(z, pts[:, 0])


def test_round_trip_with_random_poses():
    rng = np.random.default_rng(3)
    cam = Camera(hfov_deg=100.0, uptilt_deg=25.0, roll_deg=2.0)
    pos = rng.normal(size=(5, 3))
    quat = rpy_to_quat(rng.uniform(-0.8, 0.8, (5, 3)))
    r, t = camera_poses(pos, quat, cam.r_body_cam)
    pts_cam = np.concatenate([rng.uniform(-2, 2, (5, 7, 2)), rng.uniform(0.5, 20, (5, 7, 1))], -1)
    world = pts_cam @ np.swapaxes(r, -1, -2) + t[:, None]
    back = world_to_camera(world, r, t)
    np.testing.assert_allclose(back, pts_cam, atol=1e-9)
    px, z = project_points(cam.K, back)
    np.testing.assert_allclose(unproject_pixels(cam.K, px, z), pts_cam, atol=1e-9)
    single_px, _ = cam.project(world[2], pos[2], quat[2])
    np.testing.assert_allclose(single_px, px[2], atol=1e-9)


def test_uptilt_points_optical_axis_up_and_roll_about_it():
    r = body_to_camera_rotation(30.0)
    np.testing.assert_allclose(
        r[:, 2], [math.cos(math.radians(30)), 0.0, math.sin(math.radians(30))]
    )
    np.testing.assert_allclose(r[:, 0], [0.0, -1.0, 0.0], atol=1e-12)  # image right = body right
    cam = Camera(uptilt_deg=30.0)
    px, _ = cam.project(
        np.array([[5.0, 0.0, 5.0 * math.tan(math.radians(30))]]), np.zeros(3), LEVEL
    )
    np.testing.assert_allclose(px[0], [159.5, 119.5], atol=1e-9)
    rolled = body_to_camera_rotation(30.0, 10.0)
    np.testing.assert_allclose(rolled[:, 2], r[:, 2], atol=1e-12)


def test_points_behind_camera_project_to_nan():
    px, z = Camera().project(np.array([[-1.0, 0.0, 0.0]]), np.zeros(3), LEVEL)
    assert np.all(np.isnan(px)) and z[0] < 0


def test_gl_matrices_agree_with_k():
    """The PyBullet view/projection matrices map points where K does (pixel centres at integers)."""
    rng = np.random.default_rng(0)
    cam = Camera(width=320, height=240, hfov_deg=95.0, uptilt_deg=20.0, roll_deg=-3.0)
    pos, quat = np.array([1.0, -2.0, 1.5]), rpy_to_quat(np.array([[0.3, -0.2, 1.0]]))[0]
    view = np.array(cam.view_matrix(pos, quat)).reshape(4, 4, order="F")
    proj = np.array(cam.projection_matrix()).reshape(4, 4, order="F")
    r, t = cam.pose(pos, quat)
    pts = rng.uniform(-1, 1, (20, 3)) @ np.diag([1.0, 1.0, 1.0]) + np.array([0.0, 0.0, 6.0])
    world = pts @ r.T + t
    clip = (proj @ view @ np.c_[world, np.ones(len(world))].T).T
    ndc = clip[:, :3] / clip[:, 3:]
    u = (ndc[:, 0] + 1) / 2 * cam.width - 0.5
    v = (1 - ndc[:, 1]) / 2 * cam.height - 0.5
    px, _ = cam.project(world, pos, quat)
    np.testing.assert_allclose(np.c_[u, v], px, atol=1e-6)
    # A band of rows r0:r1 (a glossy floor's reflection) is the same image, cropped.
    r0, r1 = 100, 230
    band = np.array(cam.projection_matrix(rows=(r0, r1))).reshape(4, 4, order="F")
    clip = (band @ view @ np.c_[world, np.ones(len(world))].T).T
    ndc = clip[:, :3] / clip[:, 3:]
    np.testing.assert_allclose((ndc[:, 0] + 1) / 2 * cam.width - 0.5, px[:, 0], atol=1e-6)
    np.testing.assert_allclose((1 - ndc[:, 1]) / 2 * (r1 - r0) - 0.5, px[:, 1] - r0, atol=1e-6)


def test_from_params():
    cam = Camera.from_params(CameraParams(width=640, height=480, hfov_deg=100.0, uptilt_deg=15.0))
    assert (cam.width, cam.height, cam.hfov_deg, cam.uptilt_deg) == (640, 480, 100.0, 15.0)
    with pytest.raises(ValueError):
        Camera(hfov_deg=180.0)
