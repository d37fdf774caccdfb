from __future__ import annotations

import numpy as np
import pytest

from icarus_vision.policy.config import PerceptionNoiseConfig
from icarus_vision.policy.features import FEATURES_V2, feature_dim, obs_to_features
from icarus_vision.policy.perception_noise import ErrorModel, PerceptionNoise


def rotate_world(obs, angle):
    """The same situation with the whole world turned by ``angle`` about z."""
    c, s = np.cos(angle), np.sin(angle)
    r = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    o = obs.copy()
    for sl in (slice(0, 3), slice(3, 6), slice(12, 15)):
        o[:, sl] = o[:, sl] @ r.T
    o[:, 8] += angle
    return o


def test_features_do_not_depend_on_where_the_track_lies():
    rng = np.random.default_rng(0)
    obs = rng.normal(0, 2, (20, 15)).astype(np.float32)
    obs[:, 6:8] = rng.uniform(-0.5, 0.5, (20, 2))
    f = obs_to_features(obs)
    assert f.shape == (20, 16) and f.dtype == np.float32
    np.testing.assert_allclose(obs_to_features(rotate_world(obs, 1.3)), f, atol=1e-5)
    shifted = obs.copy()
    shifted[:, 0:2] += 100.0  # world x, y are not features
    np.testing.assert_array_equal(obs_to_features(shifted), f)
    with pytest.raises(ValueError, match="15, 21 or 25"):
        obs_to_features(np.zeros((2, 14)))


def test_racing_features_extend_the_extended_ones_and_turn_with_the_world():
    rng = np.random.default_rng(1)
    obs = rng.normal(0, 2, (20, 25)).astype(np.float32)
    obs[:, 6:8] = rng.uniform(-0.5, 0.5, (20, 2))
    yaw = rng.uniform(-np.pi, np.pi, (2, 20))
    obs[:, 15:18] = np.stack((np.cos(yaw[0]), np.sin(yaw[0]), 0 * yaw[0]), axis=1)
    obs[:, 22:25] = np.stack((np.cos(yaw[1]), np.sin(yaw[1]), 0 * yaw[1]), axis=1)
    obs[:, 21] = rng.uniform(0.8, 1.5, 20)
    f = obs_to_features(obs)
    assert f.shape == (20, 24)
    np.testing.assert_array_equal(f[:, :21], obs_to_features(obs[:, :21]))
    np.testing.assert_allclose(f[:, 21], obs[:, 21] - 1.0, atol=1e-6)
    # The gate after's direction in the heading frame: its yaw minus the drone's.
    rel = yaw[1] - obs[:, 8]
    np.testing.assert_allclose(f[:, 22:24], np.stack((np.cos(rel), np.sin(rel)), axis=1), atol=1e-5)
    turned = rotate_world(obs, 0.7)
    for sl in (slice(15, 18), slice(18, 21), slice(22, 25)):
        c, s = np.cos(0.7), np.sin(0.7)
        turned[:, sl] = obs[:, sl] @ np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]]).T
    np.testing.assert_allclose(obs_to_features(turned), f, atol=1e-5)


def test_v2_features_add_the_drone_in_the_gate_frame_and_its_crossing_point():
    """A drone 2 m before a gate facing +y, 0.3 m to its left and 0.2 m low, flying at 5 m/s
    through the plane and 1 m/s further left: it would cross 0.3 + 1 * 0.4 = 0.7 m left."""
    obs = np.zeros((1, 21), np.float32)
    obs[0, 0:3] = (-0.3, -2.0, 1.8)  # drone; the gate is at (0, 0, 2), passage direction +y
    obs[0, 3:6] = (-1.0, 5.0, 0.0)
    obs[0, 8] = 0.4  # any heading: the gate-frame features do not depend on it
    obs[0, 12:15] = (0.3, 2.0, 0.2)
    obs[0, 15:18] = (0.0, 1.0, 0.0)
    f = obs_to_features(obs, FEATURES_V2)
    assert f.shape == (1, feature_dim(21, FEATURES_V2)) == (1, 29)
    np.testing.assert_array_equal(f[:, :21], obs_to_features(obs))
    np.testing.assert_allclose(
        f[0, 21:], [-2.0 / 5, 0.3, -0.2, 1.0, 0.2, 0.0, 0.7, -0.2], atol=1e-6
    )
    past = obs.copy()
    past[0, 12:15] = (0.3, -0.5, 0.2)  # 0.5 m past the plane: the crossing is where it is
    np.testing.assert_allclose(obs_to_features(past, FEATURES_V2)[0, 27:], [0.3, -0.2], atol=1e-6)


def test_v2_features_turn_with_the_world_and_leave_basic_alone():
    rng = np.random.default_rng(4)
    obs = rng.normal(0, 2, (20, 25)).astype(np.float32)
    obs[:, 6:8] = rng.uniform(-0.5, 0.5, (20, 2))
    yaw = rng.uniform(-np.pi, np.pi, 20)
    obs[:, 15:18] = np.stack((np.cos(yaw), np.sin(yaw), 0 * yaw), axis=1)
    f = obs_to_features(obs, FEATURES_V2)
    assert f.shape == (20, 32)
    np.testing.assert_array_equal(f[:, :24], obs_to_features(obs))
    turned = rotate_world(obs, -2.1)
    c, s = np.cos(-2.1), np.sin(-2.1)
    for sl in (slice(15, 18), slice(18, 21), slice(22, 25)):
        turned[:, sl] = obs[:, sl] @ np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]]).T
    np.testing.assert_allclose(obs_to_features(turned, FEATURES_V2), f, atol=1e-4)
    basic = obs[:, :15]
    np.testing.assert_array_equal(obs_to_features(basic, FEATURES_V2), obs_to_features(basic))
    with pytest.raises(ValueError, match="unknown feature transform"):
        obs_to_features(basic, "icarus-features-v9")


def test_perception_noise_has_the_error_model_statistics():
    model = ErrorModel((0.0, 20.0), (0.05, 0.45), (0.1, 0.5))
    n = 20000
    noise = PerceptionNoise(model, n, seed=0)
    obs = np.zeros((n, 15), np.float32)
    obs[:, 2] = 2.0
    obs[:, 12] = 10.0  # gate 10 m ahead: sigma 0.25 m, miss rate 0.3
    first = noise.apply(obs, np.ones(n, bool))
    err0 = first[:, 12:15] - obs[:, 12:15]
    assert np.std(err0) == pytest.approx(0.25, rel=0.03)
    second = noise.apply(obs)
    held = np.all(second[:, 12:15] == first[:, 12:15], axis=1)
    assert held.mean() == pytest.approx(0.3, abs=0.02)
    err1 = (second - obs)[~held, 12:15]
    assert np.std(err1) == pytest.approx(0.25, rel=0.03) and abs(err1.mean()) < 0.01


def test_missed_detection_holds_the_world_estimate_while_the_drone_moves():
    model = ErrorModel((0.0, 10.0), (0.0, 0.0), (1.0, 1.0))  # always missed after the first sight
    noise = PerceptionNoise(model, 1, seed=0)
    obs = np.zeros((1, 15), np.float32)
    obs[0, 12:15] = (5.0, 0.0, 1.0)
    noise.apply(obs, np.ones(1, bool))
    moved = obs.copy()
    moved[0, 0] = 1.0
    moved[0, 12] = 4.0
    out = noise.apply(moved)
    np.testing.assert_allclose(out[0, 12:15], (4.0, 0.0, 1.0))


def test_error_model_file(tmp_path):
    p = tmp_path / "em.json"
    p.write_text(
        '{"distance_m": [1, 5, 10], "sigma_m": [0.01, 0.05, 0.2], "miss_rate": [0.0, 0.1, 0.3]}'
    )
    m = ErrorModel.load(p)
    assert m.sigma(np.array([3.0]))[0] == pytest.approx(0.03)
    bad = tmp_path / "bad.json"
    bad.write_text('{"distance_m": [1]}')
    with pytest.raises(ValueError, match="bad.json"):
        ErrorModel.load(bad)
    assert ErrorModel.from_config(PerceptionNoiseConfig()).sigma(np.array([0.0]))[
        0
    ] == pytest.approx(0.02)
