"""The gate Kalman filter: batched updates and distances equal the one-at-a-time ones."""

from __future__ import annotations

import math

import numpy as np

from icarus_vision.estimator.filter import (
    GateTrack,
    batch_mahalanobis_sq,
    heading_spread,
    kf_update,
    mahalanobis_sq,
    update_tracks,
)
from icarus_vision.estimator.pnp import GateMeasurement


def _cov(rng, n):
    a = rng.normal(0.0, 0.3, (n, 4, 4))
    return a @ np.swapaxes(a, -1, -2) + 0.01 * np.eye(4)


def _measurements(rng, n):
    covs = _cov(rng, n)
    pos = rng.normal(0.0, 1.0, (n, 3))
    yaw = rng.uniform(-3.0, 3.0, n).tolist()
    return [GateMeasurement(pos[i], yaw[i], covs[i], 5.0, 0.0) for i in range(n)]


def test_batched_distances_equal_single_ones():
    rng = np.random.default_rng(0)
    means = np.c_[rng.normal(0.0, 1.0, (5, 3)), rng.uniform(-1.5, 1.5, 5)]
    covs = _cov(rng, 5)
    zs = _measurements(rng, 6)  # three detections with two solutions each
    z = np.array([[*m.pos, m.yaw] for m in zs]).reshape(3, 2, 4)
    r = np.array([zs[0].cov, zs[2].cov, zs[4].cov])
    d2 = batch_mahalanobis_sq(means, covs, z, r)
    assert d2.shape == (3, 2, 5)
    for d in range(3):
        for k in range(2):
            m = GateMeasurement(z[d, k, :3], float(z[d, k, 3]), r[d], 5.0, 0.0)
            for j in range(5):
                assert math.isclose(
                    d2[d, k, j], mahalanobis_sq(means[j], covs[j], m), rel_tol=1e-12
                )


def test_batched_update_equals_updates_one_by_one():
    rng = np.random.default_rng(1)
    zs = _measurements(rng, 3)
    tracks = [GateTrack(rng.normal(0.0, 1.0, 3), 0.3, c, 1.0, 0.0, True) for c in _cov(rng, 3)]
    alone = [GateTrack(tr.pos.copy(), float(tr.mean[3]), tr.cov, 1.0, 0.0, True) for tr in tracks]
    update_tracks(tracks, zs, 2.0)
    for tr, one, z in zip(tracks, alone, zs, strict=True):
        mean, cov = kf_update(one.mean, one.cov, np.array([*z.pos, z.yaw]), z.cov)
        one.update(z, 2.0)
        np.testing.assert_allclose(tr.mean, mean, rtol=1e-12, atol=1e-14)
        np.testing.assert_allclose(tr.cov, cov, rtol=1e-12, atol=1e-14)
        np.testing.assert_allclose(one.cov, cov, rtol=1e-12, atol=1e-14)
        assert (tr.hits, tr.last_hit_t) == (1, 2.0)
        assert -math.pi / 2 <= tr.mean[3] < math.pi / 2
        np.testing.assert_array_equal(tr.cov, tr.cov.T)


def test_heading_widened_only_by_a_plausible_different_alternative():
    assert heading_spread(0.1, 0.1 + math.pi, 0.0) == 0.0  # the same axis
    assert heading_spread(0.1, 0.5, 200.0) == 0.0  # far less likely
    assert math.isclose(heading_spread(0.1, 0.5, 0.0), 0.5 * 0.4**2)
