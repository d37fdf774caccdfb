from __future__ import annotations

import numpy as np
import pytest

from icarus_vision.policy.config import PerceptionNoiseConfig
from icarus_vision.policy.features import obs_to_features
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
