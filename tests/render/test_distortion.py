"""Lens distortion through the pipeline: OpenCV's models, the round trip, the quadrotor file, a
render whose labels are the distorted corners, and PnP on distorted corners."""

from __future__ import annotations

import tomllib

import cv2
import numpy as np
import pytest

from icarus_vision.estimator.config import MeasurementConfig
from icarus_vision.estimator.fusion import solve_detections
from icarus_vision.gate_detect.base import GateDetection
from icarus_vision.render.camera import Camera, project_points
from icarus_vision.render.distortion import distort_pixels, undistort_pixels
from icarus_vision.render.labels import VISIBLE, frame_labels
from icarus_vision.render.scene import Scene
from icarus_vision.sim.quad import QuadError, quad_from_dict, quad_to_toml
from icarus_vision.sim.track import Gate, Track

LENSES = [
    ("radtan", (-0.3, 0.08, 0.001, -0.002)),
    ("radtan", (-0.28, 0.07, 0.0005, 0.001, -0.01)),
    ("fisheye", (-0.05, 0.01, -0.002, 0.0003)),
]
LEVEL = np.array([0.0, 0.0, 0.0, 1.0])
EYE = np.array([0.0, 0.0, 2.0])


@pytest.mark.parametrize("model, coeffs", LENSES)
def test_distortion_is_opencvs_and_undistortion_inverts_it(model, coeffs):
    cam = Camera(distortion=model, dist_coeffs=coeffs)
    k = cam.K
    rng = np.random.default_rng(0)
    pin = rng.uniform([-10.0, -10.0], [330.0, 250.0], (500, 2))
    xyz = np.column_stack([(pin - k[:2, 2]) / k[0, 0], np.ones(len(pin))])
    if model == "radtan":
        ref, _ = cv2.projectPoints(xyz, np.zeros(3), np.zeros(3), k, np.array(coeffs))
    else:
        ref, _ = cv2.fisheye.projectPoints(xyz[:, None], np.zeros(3), np.zeros(3), k,
                                           np.array(coeffs))  # fmt: skip
    distorted = cam.distort(pin)
    np.testing.assert_allclose(distorted, ref.reshape(-1, 2), atol=1e-9)
    assert np.abs(distorted - pin).max() > 5.0  # a real lens, not the identity
    np.testing.assert_allclose(cam.undistort(distorted), pin, atol=0.01)
    np.testing.assert_allclose(undistort_pixels(k, distorted, model, coeffs), pin, atol=1e-6)


def test_no_distortion_is_the_identity_and_nan_stays_nan():
    cam = Camera()
    px = np.array([[1.0, 2.0], [np.nan, np.nan]])
    np.testing.assert_array_equal(cam.distort(px), px)
    assert not cam.distorted and cam.pinhole_cover() == (cam, (0, 0))
    d = distort_pixels(cam.K, px, "radtan", (-0.2, 0.0, 0.0, 0.0))
    assert np.isnan(d[1]).all() and np.isfinite(d[0]).all()


def test_the_quadrotor_file_carries_the_lens():
    q = quad_from_dict({"camera": {"distortion": "fisheye", "dist_coeffs": [0.1, 0, 0, 0]}})
    cam = Camera.from_params(q.camera)
    assert cam.distortion == "fisheye" and cam.dist_coeffs == (0.1, 0.0, 0.0, 0.0)
    assert Camera.from_params(quad_from_dict({}).camera).distortion == "none"
    assert quad_from_dict(tomllib.loads(quad_to_toml(q))) == q
    for bad, needle in [({"distortion": "fish"}, "one of none, radtan, fisheye"),
                        ({"distortion": "radtan", "dist_coeffs": [0.1]}, "4 or 5 coefficients"),
                        ({"dist_coeffs": [0.1]}, "'none' takes 0"),
                        ({"distortion": "fisheye", "dist_coeffs": [0, 0, 0, float("nan")]},
                         "finite")]:  # fmt: skip
        with pytest.raises(QuadError, match=needle):
            quad_from_dict({"camera": bad}, source="q.toml")


@pytest.mark.parametrize("model, coeffs", [LENSES[0], LENSES[2]])
def test_a_distorted_render_labels_the_distorted_corners_to_the_pixel(model, coeffs):
    """A gate off to the side, where the lens moves it most: each labelled corner sits on the
    rendered frame with the opening's background 2.5 px inward, and the labels are far from
    where the pinhole camera would put them."""
    track = Track("side", (Gate((4.0, 1.9, 2.6), 0.0),), start_pos=(0.0, 0.0, 0.2))
    lens = Camera(uptilt_deg=0.0, distortion=model, dist_coeffs=coeffs)
    with Scene(track, lens) as scene:
        frame = scene.render(EYE, LEVEL)
        (lab,) = frame_labels(scene, frame, EYE, LEVEL)
        body = scene.gate_bodies[0]
    assert frame.rgb.shape == (240, 320, 3) and list(lab.visibility) == [VISIBLE] * 4
    pinhole, _ = project_points(lens.K, lens.to_camera(track.gates[0].corners(), EYE, LEVEL))
    assert np.linalg.norm(lab.corners_px - pinhole, axis=1).max() > 8.0
    centre = lab.corners_px.mean(axis=0)
    for u, v in lab.corners_px:
        ui, vi = int(round(u)), int(round(v))
        assert (frame.seg[vi - 1 : vi + 2, ui - 1 : ui + 2] == body).any()
        inward = (centre - (u, v)) / np.linalg.norm(centre - (u, v))
        iu, iv = np.round(np.array([u, v]) + 2.5 * inward).astype(int)
        assert frame.seg[iv, iu] != body
    x, y, w, h = lab.bbox
    assert x <= lab.corners_px[:, 0].min() and x + w >= lab.corners_px[:, 0].max()


@pytest.mark.parametrize("model, coeffs", LENSES)
def test_pnp_on_distorted_corners_recovers_the_pose(model, coeffs):
    """Corners through the lens: solved undistorted, the gate is where it is; solved as if
    pinhole, it is not."""
    lens = Camera(uptilt_deg=0.0, distortion=model, dist_coeffs=coeffs)
    gate = Gate((5.0, 2.2, 3.1), 20.0)
    corners, _ = lens.project(gate.corners(), EYE, LEVEL)
    r_wc, t_wc = lens.pose(EYE, LEVEL)
    det = [GateDetection(corners, np.ones(4), 1.0)]

    def centre(undistort):
        sols, reasons = solve_detections(det, lens.K, (320, 240), r_wc, t_wc,
                                         MeasurementConfig(), 1.0, undistort)  # fmt: skip
        assert reasons == [None]
        t_cam = sols.t_cam_gate[0, 0]
        return r_wc @ t_cam + t_wc

    np.testing.assert_allclose(centre(lens.undistort), gate.pos, atol=1e-6)
    assert np.linalg.norm(centre(None) - np.asarray(gate.pos)) > 0.1
