"""Square PnP on synthetic ground truth: sampled gate poses, projected corners, pixel noise."""

from __future__ import annotations

import math

import numpy as np
import pytest

from icarus_vision.estimator.config import MeasurementConfig, config_for_detector
from icarus_vision.estimator.pnp import (
    check_corners,
    gate_yaw,
    measure_candidates,
    measurement_covariance,
    pose_covariance,
    solve_square_pnp,
    to_measurement,
    wrap_axis,
)
from icarus_vision.sim.track import Gate

from .conftest import CAM, odom_at

CFG = MeasurementConfig()


def _sample_view(rng, dist, max_angle_deg):
    """A drone at the origin, 2 m up, heading +x; a gate ``dist`` ahead in view, facing the drone
    within ``max_angle_deg``."""
    az = rng.uniform(-0.35, 0.35)
    el = rng.uniform(-0.05, 0.3)
    centre = np.array([0.0, 0.0, 2.0]) + dist * np.array(
        [math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)]
    )
    yaw = math.degrees(az) + rng.uniform(-max_angle_deg, max_angle_deg)
    return Gate(tuple(centre), yaw_deg=yaw)


def _project(gate, od):
    px, _ = CAM.project(gate.corners(), od.pos, od.quat)
    return px


def test_exact_corners_give_the_exact_pose():
    rng = np.random.default_rng(0)
    od = odom_at(0.0, [0.0, 0.0, 2.0])
    r_wc, t_wc = CAM.pose(od.pos, od.quat)
    for _ in range(20):
        gate = _sample_view(rng, rng.uniform(2.0, 12.0), 50.0)
        sols = solve_square_pnp(_project(gate, od), gate.size, CAM.K)
        best = sols[0]
        np.testing.assert_allclose(t_wc + r_wc @ best.t_cam_gate, gate.pos, atol=1e-6)
        assert abs(wrap_axis(gate_yaw(r_wc @ best.r_cam_gate) - gate.yaw)) < 1e-6
        assert best.sq_err < 1e-12


@pytest.mark.parametrize("sigma", [0.5, 1.0, 2.0])
def test_error_scales_with_sigma_and_distance(sigma):
    """Position error within a bound ∝ σ·d²/(f·s) (depth) and the covariance is honest."""
    rng = np.random.default_rng(1)
    od = odom_at(0.0, [0.0, 0.0, 2.0])
    r_wc, t_wc = CAM.pose(od.pos, od.quat)
    cfg = MeasurementConfig(pixel_sigma=sigma, odometry_att_sigma_deg=0.0, min_sigma_m=0.0)
    f = CAM.K[0, 0]
    chi2 = []
    for _ in range(200):
        d = rng.uniform(1.5, 10.0)
        gate = _sample_view(rng, d, 40.0)
        px = _project(gate, od) + rng.normal(0.0, sigma, (4, 2))
        if check_corners(px, CAM.width, CAM.height, cfg) is not None:
            continue  # partly out of view
        sols, costs = measure_candidates(px, gate.size, CAM.K, r_wc, t_wc, cfg)
        cov6 = pose_covariance(CAM.K, sols[0].r_cam_gate, sols[0].t_cam_gate, gate.size, sigma)
        cov = measurement_covariance(cov6, d, r_wc, cfg)
        m = to_measurement(sols[0], cov, r_wc, t_wc)
        err = m.pos - np.asarray(gate.pos)
        bound = 8.0 * sigma * d * d / (f * gate.size) + 4.0 * sigma * d / f
        assert np.linalg.norm(err) < bound
        chi2.append(err @ np.linalg.solve(m.cov[:3, :3], err))
    assert len(chi2) > 100
    # cov_scale 1.5 makes the covariance a little conservative: χ²(3) mean 3 → about 2.
    assert 1.0 < np.mean(chi2) < 4.0
    assert np.percentile(chi2, 95) < 11.3  # χ²(3) 99 %


def test_covariance_grows_with_distance_and_viewing_angle():
    od = odom_at(0.0, [0.0, 0.0, 2.0])
    r_wc, _ = CAM.pose(od.pos, od.quat)

    def depth_sigma(dist, yaw_deg):
        gate = Gate((dist, 0.0, 2.0), yaw_deg=yaw_deg)
        sol = solve_square_pnp(_project(gate, od), 1.0, CAM.K)[0]
        return math.sqrt(pose_covariance(CAM.K, sol.r_cam_gate, sol.t_cam_gate, 1.0, 1.0)[2, 2])

    assert depth_sigma(8.0, 0.0) > 3.0 * depth_sigma(4.0, 0.0)  # ~ d²
    assert depth_sigma(4.0, 60.0) > 1.2 * depth_sigma(4.0, 0.0)


@pytest.mark.parametrize("yaw_deg", [-55.0, -40.0, 40.0, 55.0])
def test_ambiguity_resolved_for_oblique_views(yaw_deg):
    """Oblique views from above or below: the upright-gate prior picks the right solution."""
    rng = np.random.default_rng(2)
    for z in (0.8, 3.5):
        od = odom_at(0.0, [0.0, 0.0, z], pitch=0.3 if z > 2 else -0.1)
        r_wc, t_wc = CAM.pose(od.pos, od.quat)
        gate = Gate((5.0, 0.5, 2.0), yaw_deg=yaw_deg)
        ok = 0
        for _ in range(20):
            px = _project(gate, od) + rng.normal(0.0, 0.5, (4, 2))
            sols, _ = measure_candidates(px, 1.0, CAM.K, r_wc, t_wc, CFG)
            yaw = gate_yaw(r_wc @ sols[0].r_cam_gate)
            ok += abs(math.degrees(wrap_axis(yaw - gate.yaw))) < 10.0
        assert ok >= 18


@pytest.mark.parametrize(
    "corners,reason",
    [
        ([[100, 100], [150, 100], [150, np.nan], [100, 150]], "non_finite"),
        ([[100, 100], [150, np.inf], [150, 150], [100, 150]], "non_finite"),
        ([[100, 100], [400, 100], [400, 150], [100, 150]], "outside_image"),
        ([[-5, 100], [150, 100], [150, 150], [-5, 150]], "outside_image"),
        # cut by the top edge: two corners just past it (the image starts at -0.5)
        ([[154, -0.4], [163, -0.8], [157, 28], [150, 26]], "outside_image"),
        ([[100, -0.4], [150, -0.4], [150, 50], [100, 50]], None),
        ([[100, 100], [101, 100], [101, 101], [100, 101]], "too_small"),
        ([[100, 100], [150, 100], [200, 100], [250, 100]], "degenerate"),  # collinear
        ([[100, 100], [150, 150], [150, 100], [100, 150]], "degenerate"),  # crossed
        ([[150, 100], [100, 100], [100, 150], [150, 150]], "degenerate"),  # mirrored
        ([[100, 100], [150, 100], [150, 150], [100, 150]], None),
    ],
)
def test_corner_checks(corners, reason):
    assert check_corners(np.array(corners, float), 320, 240, CFG) == reason


def test_wrap_axis_same_for_floats_and_arrays():
    rng = np.random.default_rng(3)
    angles = np.r_[rng.uniform(-20.0, 20.0, 500), np.arange(-8, 9) * (np.pi / 2)]
    wrapped = wrap_axis(angles)
    assert np.all((wrapped >= -np.pi / 2) & (wrapped < np.pi / 2))
    for a, w in zip(angles.tolist(), wrapped.tolist(), strict=True):
        assert wrap_axis(a) == w and isinstance(wrap_axis(a), float)


def test_pose_covariance_batched_equals_one_at_a_time():
    rng = np.random.default_rng(4)
    od = odom_at(0.0, [0.0, 0.0, 2.0])
    sols = [
        solve_square_pnp(_project(_sample_view(rng, d, 50.0), od), 1.0, CAM.K)[0]
        for d in (2.0, 5.0, 9.0)
    ]
    r = np.array([s.r_cam_gate for s in sols])
    t = np.array([s.t_cam_gate for s in sols])
    batch = pose_covariance(CAM.K, r, t, 1.5, 2.0)
    assert batch.shape == (3, 6, 6)
    for cov, s in zip(batch, sols, strict=True):
        one = pose_covariance(CAM.K, s.r_cam_gate, s.t_cam_gate, 1.5, 2.0)
        np.testing.assert_allclose(cov, one, rtol=1e-12, atol=1e-15)


def test_range_inflation_doubles_the_covariance_at_its_distance():
    rng = np.random.default_rng(0)
    a = rng.normal(size=(6, 6))
    cov6 = a @ a.T + np.eye(6)
    r = np.eye(3)
    off = MeasurementConfig(odometry_att_sigma_deg=0.0, min_sigma_m=0.0)
    on = MeasurementConfig(odometry_att_sigma_deg=0.0, min_sigma_m=0.0, range_inflation_m=10.0)
    base = measurement_covariance(cov6, 10.0, r, off)
    np.testing.assert_allclose(measurement_covariance(cov6, 10.0, r, on), 2.0 * base)
    np.testing.assert_allclose(measurement_covariance(cov6, 0.0, r, on), base)
    batched = measurement_covariance(np.stack([cov6, cov6]), np.array([0.0, 10.0]), r, on)
    np.testing.assert_allclose(batched[1], 2.0 * base)
    with pytest.raises(ValueError, match="range_inflation_m"):
        MeasurementConfig(range_inflation_m=0.0)


def test_the_position_heading_correlation_can_be_dropped():
    """Without the correlation only the position-heading block is zeroed; the CNN's estimator
    drops it, the oracle's keeps it."""
    rng = np.random.default_rng(1)
    a = rng.normal(size=(6, 6))
    cov6 = a @ a.T + np.eye(6)
    r = np.eye(3)[[2, 0, 1]]  # a rotation (a permutation of the axes)
    kept = measurement_covariance(cov6, 5.0, r, MeasurementConfig())
    dropped = measurement_covariance(cov6, 5.0, r, MeasurementConfig(heading_correlation=False))
    assert np.abs(kept[:3, 3]).max() > 1e-3
    np.testing.assert_array_equal(dropped[:3, 3], 0.0)
    np.testing.assert_array_equal(dropped[3, :3], 0.0)
    np.testing.assert_allclose(dropped[:3, :3], kept[:3, :3])
    assert dropped[3, 3] == kept[3, 3]
    assert not config_for_detector("cnn").measurement.heading_correlation
    assert config_for_detector("oracle").measurement.heading_correlation
