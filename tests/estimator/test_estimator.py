"""The filter and the estimator on synthetic approaches: convergence, outliers, gaps, passages."""

from __future__ import annotations

import numpy as np
import pytest

from icarus_vision.estimator import (
    EstimatorConfig,
    GateEstimator,
    OdometryReading,
    displaced_map,
    fill_observation,
)
from icarus_vision.gate_detect import GateDetection, OracleDetector
from icarus_vision.sim.track import Gate, Track

from .conftest import CAM, odom_at

RATE = 30.0


def _fly(est, oracle, t0, t1, x0, x1, detections=True, extra=None):
    """Fly straight from (x0, 0, 2) to (x1, 0, 2) between t0 and t1 at the camera rate."""
    out = []
    for t in np.arange(t0, t1, 1.0 / RATE):
        x = x0 + (x1 - x0) * (t - t0) / (t1 - t0)
        od = odom_at(t, [x, 0.0, 2.0])
        if detections:
            dets = oracle.detect_pose(od.pos, od.quat)
            if extra is not None:
                dets = dets + extra(t)
            out.append(est.update(od, dets))
        else:
            out.append(est.predict(od))
    return out


def _truth_rel(gate: Gate, x: float) -> np.ndarray:
    return np.asarray(gate.pos) - np.array([x, 0.0, 2.0])


@pytest.mark.parametrize("offset", [0.4, 1.5])
def test_converges_from_a_wrong_prior(two_gates, offset):
    prior = Track("prior", (Gate((6.0 - offset, offset, 2.0 + offset / 2)), two_gates.gates[1]))
    est = GateEstimator(CAM, EstimatorConfig(map_sigma_m=0.3), prior)
    oracle = OracleDetector(two_gates, CAM, sigma_px=0.5, seed=0)
    before = est.predict(odom_at(0.0, [0.0, 0.0, 2.0]))
    assert np.linalg.norm(before.rel_world - _truth_rel(two_gates.gates[0], 0.0)) > 0.5
    first = _fly(est, oracle, 0.0, 1.0, 0.0, 1.5)
    last = first[-1]
    x = 0.0 + 1.5 * (last.t / 1.0)
    assert np.linalg.norm(last.rel_world - _truth_rel(two_gates.gates[0], x)) < 0.05
    if offset > 1.0:
        assert est.counts["reinit"] == 1


def test_a_gate_of_the_map_stays_within_its_limit(two_gates):
    """With ``map_limit_sigmas`` the map is trusted to within that many ``map_sigma_m``: a gate
    the map has 1.5 m off is neither matched nor re-initialised beyond 0.6 m of the map's place
    (without the limit it converges to the truth: above), while a gate 0.45 m off converges."""
    for offset, converges in ((1.5, False), (0.3, True)):
        moved = Gate((6.0 - offset, offset, 2.0 + offset / 2))
        prior = Track("prior", (moved, two_gates.gates[1]))
        est = GateEstimator(CAM, EstimatorConfig(map_sigma_m=0.3, map_limit_sigmas=2.0), prior)
        oracle = OracleDetector(two_gates, CAM, sigma_px=0.5, seed=0)
        last = _fly(est, oracle, 0.0, 1.0, 0.0, 1.5)[-1]
        x = 1.5 * last.t
        err = np.linalg.norm(last.rel_world - _truth_rel(two_gates.gates[0], x))
        assert np.linalg.norm(est.tracks[0].pos - np.asarray(moved.pos)) <= 0.6 + 1e-9
        assert (err < 0.05) == converges and est.counts["reinit"] == 0, (offset, err)


def test_rejects_injected_outliers(two_gates):
    prior = displaced_map(two_gates, 0.2, 3.0, seed=1)
    est = GateEstimator(CAM, EstimatorConfig(), prior)
    oracle = OracleDetector(two_gates, CAM, sigma_px=0.5, seed=0)
    rng = np.random.default_rng(4)
    # A persistent false gate 1.5 m beside the real one, and random quadrilaterals.
    fake = OracleDetector(Track("fake", (Gate((6.0, 1.5, 2.5)),)), CAM, seed=1)

    def extra(t):
        od = odom_at(t, [0.0, 0.0, 2.0])
        c = rng.uniform(20, 200, 2)
        rand = GateDetection(c + np.array([[0, 0], [30, 0], [30, 30], [0, 30]]), np.ones(4), 1.0)
        return fake.detect_pose(od.pos, od.quat) + [rand]

    res = _fly(est, oracle, 0.0, 1.5, 0.0, 2.0, extra=extra)
    x = 2.0 * res[-1].t / 1.5
    assert np.linalg.norm(res[-1].rel_world - _truth_rel(two_gates.gates[0], x)) < 0.05
    assert est.counts["outliers"] >= len(res)  # at least one outlier per frame
    assert est.counts["reinit"] == 0


@pytest.mark.parametrize("turned", [False, True])
def test_a_gate_out_of_view_is_not_moved_to_a_persistent_false_detection(two_gates, turned):
    """Just through gate 0 and turning back toward it (a hairpin), the camera sees a gate-like
    thing 2 m from where gate 0 is, frame after frame, and never gate 0 itself. Facing away
    from gate 0 its silence says nothing about the map: it stays put. Facing it, the map puts it
    in view and vision does not find it there: the map is re-initialised to what vision sees."""
    est = GateEstimator(CAM, EstimatorConfig(), two_gates)
    oracle = OracleDetector(two_gates, CAM, sigma_px=0.5, seed=0)
    _fly(est, oracle, 0.0, 1.0, 0.0, 6.5)  # approach and pass gate 0
    # Turned: 3 m past gate 0 facing it, the false gate 1.9 m beside it. Not turned: just past
    # gate 0, facing on, the false gate 2.5 m ahead of it.
    here, yaw, false_gate = ((9.0, np.pi, (6.0, 1.9, 2.3)) if turned else
                             (6.5, 0.0, (8.5, 0.6, 2.3)))  # fmt: skip
    fake = OracleDetector(Track("fake", (Gate(false_gate, yaw_deg=180.0 * turned),)), CAM, seed=1)
    for t in np.arange(1.0, 2.0, 1.0 / RATE):
        od = odom_at(t, [here, 0.0, 2.0], yaw=yaw)
        assert fake.detect_pose(od.pos, od.quat)
        est.update(od, fake.detect_pose(od.pos, od.quat))
    moved = np.linalg.norm(est.tracks[0].pos - np.array([6.0, 0.0, 2.0]))
    assert est.counts["outliers"] >= 3
    if turned:
        assert est.counts["reinit"] == 1 and moved > 1.0
    else:
        assert est.counts["reinit"] == 0 and moved < 0.05


@pytest.mark.parametrize("vote", [2.0, 0.0])
def test_a_gate_one_bad_detection_moved_is_moved_back_by_the_good_ones(two_gates, vote):
    """One accepted bad detection (a gate cut by the image's edge, say) puts gate 0, not seen
    before, 1.2 m off with a confident covariance; the good detections that follow are outliers
    to it. They soon outnumber its one hit, so it is re-initialised to them within a few frames,
    not only once the bad hit has left the window (0.5 s). The vote off (0): a hit never blocks."""
    from icarus_vision.estimator.config import FilterConfig
    from icarus_vision.estimator.pnp import GateMeasurement

    est = GateEstimator(CAM, EstimatorConfig(filter=FilterConfig(reinit_vote=vote)), two_gates)
    oracle = OracleDetector(two_gates, CAM, sigma_px=0.5, seed=0)
    bad = GateMeasurement(
        np.array([6.0, 1.2, 2.0]), 0.0, np.diag([1e-2, 1e-2, 1e-2, 1e-3]), 6.0, 0.0
    )
    est.tracks[0].reinit(bad, 0.0)
    res = _fly(est, oracle, 1.0 / RATE, 0.25, 0.0, 0.5)
    x = 0.5 * (res[-1].t - 1.0 / RATE) / (0.25 - 1.0 / RATE)
    assert est.counts["reinit"] == 1 and est.counts["outliers"] <= 4
    assert np.linalg.norm(res[-1].rel_world - _truth_rel(two_gates.gates[0], x)) < 0.1


def test_survives_a_second_without_detections(two_gates):
    est = GateEstimator(CAM, EstimatorConfig(), displaced_map(two_gates, 0.2, 3.0, seed=1))
    oracle = OracleDetector(two_gates, CAM, sigma_px=0.5, seed=0)
    seen = _fly(est, oracle, 0.0, 1.0, 0.0, 1.0)[-1]
    blind = _fly(est, oracle, 1.0, 2.0, 1.0, 2.5, detections=False)
    assert all(not e.measured for e in blind)
    assert np.trace(blind[-1].cov_world) > np.trace(seen.cov_world)
    assert blind[-1].since_seen_s > 0.9
    # Carried by odometry: still right at the end of the gap.
    x = 1.0 + 1.5 * (blind[-1].t - 1.0)
    assert np.linalg.norm(blind[-1].rel_world - _truth_rel(two_gates.gates[0], x)) < 0.05
    again = _fly(est, oracle, 2.0, 2.3, 2.5, 3.0)
    assert again[-1].measured


def test_switches_gate_on_passage(two_gates):
    est = GateEstimator(CAM, EstimatorConfig(), displaced_map(two_gates, 0.2, 3.0, seed=1))
    oracle = OracleDetector(two_gates, CAM, sigma_px=0.5, seed=0)
    res = _fly(est, oracle, 0.0, 3.0, 0.0, 9.0)
    targets = [e.target for e in res]
    assert targets[0] == 0 and targets[-1] == 1
    i = targets.index(1)
    x = 9.0 * res[i].t / 3.0
    assert x >= 6.0 and 9.0 * res[i - 1].t / 3.0 < 6.0  # switched on the step that crossed
    assert est.counts["passages"] == 1
    assert (
        np.linalg.norm(res[-1].rel_world - _truth_rel(two_gates.gates[1], 9.0 - 3.0 / RATE)) < 0.3
    )


@pytest.mark.parametrize("shift, passed", [(-0.15, True), (-0.9, False)])
def test_a_plane_moved_back_past_the_drone_counts_as_passed(two_gates, shift, passed):
    """Vision moves the gate between two checks so that the drone, just before the plane, is
    now just behind it: it flies on, never crosses the plane again, and would chase a gate it
    has flown through. A small shift counts as the passage; a jump of more than half the gate's
    size (a re-initialised gate) does not."""
    est = GateEstimator(CAM, EstimatorConfig(), two_gates)
    est.predict(odom_at(0.00, (5.80, 0, 2)))
    est.predict(odom_at(0.02, (5.95, 0, 2)))  # 5 cm before the plane
    assert est.target == 0
    est.tracks[est.passage_gate[0]].mean[0] += shift  # what a vision update does
    est.predict(odom_at(0.04, (6.10, 0, 2)))
    est.predict(odom_at(0.06, (6.25, 0, 2)))
    assert est.target == int(passed) and est.counts["passages"] == int(passed)


def test_a_late_image_does_not_pass_a_hairpin_gate_backwards():
    """Hairpin: the gate just passed is the next passage, the other way. An image taken before the
    passage, fused after it (latency), moves the estimator back in time through that plane: it
    must not count as flying through the gate again."""
    g = Gate((5.0, 0.0, 2.0))
    hairpin = Track("hp", (g, Gate(g.pos, yaw_deg=180.0), Gate((-1.0, 4.0, 2.0), yaw_deg=135.0)))
    est = GateEstimator(CAM, EstimatorConfig(), hairpin)
    est.predict(odom_at(0.00, (4.6, 0, 2)))
    est.predict(odom_at(0.02, (5.2, 0, 2)))  # through gate 0 along +x
    assert est.target == 1
    est.update(odom_at(0.00, (4.6, 0, 2)), [])  # the image of t = 0, one frame late
    est.predict(odom_at(0.04, (5.6, 0, 2)))
    assert est.target == 1 and est.counts["passages"] == 1
    est.predict(odom_at(0.50, (5.6, 0.1, 2), yaw=np.pi))
    est.predict(odom_at(0.52, (4.8, 0.1, 2), yaw=np.pi))  # back through it along -x
    assert est.target == 2


def test_map_free_finds_the_gate_ahead(two_gates):
    est = GateEstimator(CAM, EstimatorConfig(mode="map-free"))
    oracle = OracleDetector(two_gates, CAM, sigma_px=0.5, seed=0)
    first = est.predict(odom_at(0.0, [0.0, 0.0, 2.0]))
    assert not first.valid and np.all(np.isfinite(first.rel_world))
    res = _fly(est, oracle, 0.0, 3.0, 0.0, 9.0)
    i = next(k for k, e in enumerate(res) if e.valid)
    assert i < 5
    before = [e for e in res[i:] if e.target == 0]
    x = 9.0 * before[-1].t / 3.0
    assert np.linalg.norm(before[-1].rel_world - _truth_rel(two_gates.gates[0], x)) < 0.05
    assert res[-1].target == 1
    assert np.linalg.norm(res[-1].gate_pos - np.array(two_gates.gates[1].pos)) < 0.3


def test_degenerate_corners_are_rejected_and_counted(two_gates):
    est = GateEstimator(CAM, EstimatorConfig(), two_gates)
    bad = [
        GateDetection(np.full((4, 2), np.nan), np.ones(4), 1.0),
        GateDetection([[10, 10], [50, 10], [90, 10], [130, 10]], np.ones(4), 1.0),
        GateDetection([[-50, 10], [50, 10], [50, 90], [-50, 90]], np.ones(4), 1.0),
        GateDetection([[10, 10], [10.5, 10], [10.5, 10.5], [10, 10.5]], np.ones(4), 1.0),
    ]
    e = est.update(odom_at(0.0, [0.0, 0.0, 2.0]), bad)
    assert np.all(np.isfinite(e.rel_world)) and not e.measured
    c = est.counts
    assert c["detections"] == 4 and c["accepted"] == 0
    assert (c["rejected_non_finite"], c["rejected_degenerate"]) == (1, 1)
    assert (c["rejected_outside_image"], c["rejected_too_small"]) == (1, 1)


@pytest.mark.parametrize("field", ["pos", "vel", "quat", "omega", "t"])
def test_non_finite_odometry_is_refused(two_gates, field):
    est = GateEstimator(CAM, EstimatorConfig(), two_gates)
    od = odom_at(0.0, [0.0, 0.0, 2.0])
    kw = {k: getattr(od, k) for k in ("t", "pos", "vel", "quat", "omega")}
    kw[field] = np.nan if field == "t" else np.full_like(kw[field], np.nan)
    with pytest.raises(ValueError, match="not finite"):
        est.predict(OdometryReading(**kw))
    with pytest.raises(ValueError, match="not finite"):
        est.update(OdometryReading(**kw), [])


def test_map_aided_needs_a_prior_and_modes_are_checked():
    with pytest.raises(ValueError, match="prior"):
        GateEstimator(CAM, EstimatorConfig())
    with pytest.raises(ValueError, match="mode"):
        EstimatorConfig(mode="guess")


def test_observation_slots_world_and_body(two_gates):
    est = GateEstimator(CAM, EstimatorConfig(), two_gates)
    od = odom_at(0.0, [1.0, 0.0, 2.0], yaw=np.pi / 2)
    e = est.predict(od)
    np.testing.assert_allclose(e.rel_world, [5.0, 0.0, 0.0], atol=1e-9)
    np.testing.assert_allclose(e.rel_body, [0.0, -5.0, 0.0], atol=1e-9)
    obs = np.arange(15, dtype=np.float32)
    w, b = fill_observation(obs, e), fill_observation(obs[None], e, "body")
    np.testing.assert_allclose(w[12:], e.rel_world)
    np.testing.assert_allclose(b[0, 12:], e.rel_body)
    np.testing.assert_array_equal(w[:12], obs[:12])
    assert w.dtype == np.float32 and obs[12] == 12.0
    np.testing.assert_allclose(np.trace(e.cov_body), np.trace(e.cov_world))


def test_racing_observation_slots_come_from_the_map():
    """The racing observation's opening side and the gate after's heading come from the map; once
    the first gate is passed, the last gate repeats as the gate after."""
    from icarus_vision.racing.loop import extra_from_estimate

    track = Track(
        "sizes", (Gate((6.0, 0.0, 2.0), size=0.8), Gate((14.0, 1.0, 2.0), yaw_deg=30.0, size=1.4))
    )
    est = GateEstimator(CAM, EstimatorConfig(), track)
    od = odom_at(0.0, [0.0, 0.0, 2.0])
    first = est.predict(od)
    assert first.size == pytest.approx(0.8)
    assert est.gate_after_yaw() == pytest.approx(np.radians(30.0))
    extra = extra_from_estimate(first, est, od, 25)
    np.testing.assert_allclose(extra[:3], [1.0, 0.0, 0.0], atol=1e-9)  # the next gate's heading
    np.testing.assert_allclose(extra[3:6], [14.0, 1.0, 0.0], atol=1e-9)  # the gate after
    assert extra[6] == pytest.approx(0.8)
    np.testing.assert_allclose(extra[7:], [np.cos(np.radians(30)), np.sin(np.radians(30)), 0.0])
    assert extra_from_estimate(first, est, od, 21).shape == (6,)
    assert extra_from_estimate(first, est, od, 15) is None
    oracle = OracleDetector(track, CAM, sigma_px=0.5, seed=0)
    after = _fly(est, oracle, 0.0, 3.0, 0.0, 9.0)[-1]
    assert after.target == 1 and after.size == pytest.approx(1.4)
    assert est.gate_after_yaw() == pytest.approx(np.radians(30.0), abs=0.05)
    free = GateEstimator(CAM, EstimatorConfig(mode="map-free"))
    est0 = free.predict(od)
    assert free.gate_after_yaw() is None
    np.testing.assert_allclose(
        extra_from_estimate(est0, free, od, 25)[7:], extra_from_estimate(est0, free, od, 25)[:3]
    )


@pytest.mark.parametrize("limit, passed", [(3.0, True), (np.inf, False)])
def test_the_passage_heading_stays_near_the_maps(limit, passed):
    """A gate whose filtered heading has turned 70° from the map's (PnP's ambiguity held the wrong
    solution): its passage plane stays within 3 σ of the map's heading, so a drone flying through
    the opening at 25° off the map's heading is counted through it; unlimited, that plane is
    crossed backwards and the passage is never counted."""
    track = Track("one", (Gate((6.0, 0.0, 2.0)), Gate((14.0, -4.0, 2.0))))
    est = GateEstimator(CAM, EstimatorConfig(map_yaw_limit_sigmas=limit), track)
    est.tracks[0].mean[3] = np.radians(70.0)
    yaw = np.radians(-25.0)
    for s in np.linspace(-6.0, 3.0, 60):
        pos = [6.0 + s * np.cos(yaw), s * np.sin(yaw), 2.0]
        e = est.predict(odom_at(1.0 + s, pos, yaw=float(yaw)))
        if s < -1.0:
            heading = np.degrees(e.yaw)
            assert heading == pytest.approx(30.0 if np.isfinite(limit) else 70.0, abs=1e-6)
    assert (est.target == 1) == passed


def test_detections_under_min_score_are_not_measured(two_gates):
    """A detector's doubtful reads (scored under ``min_score``) are neither measurements nor
    outliers; the sure ones are measured as before."""
    from dataclasses import replace

    from icarus_vision.estimator.config import DETECTOR_MIN_SCORE, config_for_detector

    fake = OracleDetector(Track("fake", (Gate((6.0, 1.5, 2.5)),)), CAM, seed=1)

    def doubtful(t):
        od = odom_at(t, [0.0, 0.0, 2.0])
        return [replace(d, score=0.4) for d in fake.detect_pose(od.pos, od.quat)]

    for floor in (0.0, 0.7):
        cfg = EstimatorConfig()
        cfg = replace(cfg, measurement=replace(cfg.measurement, min_score=floor))
        est = GateEstimator(CAM, cfg, displaced_map(two_gates, 0.2, 3.0, seed=1))
        oracle = OracleDetector(two_gates, CAM, sigma_px=0.5, seed=0)
        res = _fly(est, oracle, 0.0, 1.5, 0.0, 2.0, extra=doubtful)
        x = 2.0 * res[-1].t / 1.5
        assert np.linalg.norm(res[-1].rel_world - _truth_rel(two_gates.gates[0], x)) < 0.05
        if floor == 0.0:
            assert est.counts["outliers"] > len(res) // 2 and est.counts["rejected_low_score"] == 0
        else:
            assert est.counts["outliers"] == 0 and est.counts["rejected_low_score"] == len(res)
            assert est.counts["accepted"] >= len(res)
    assert config_for_detector("cnn").measurement.min_score == DETECTOR_MIN_SCORE["cnn"]
    assert config_for_detector("opencv").measurement.min_score == 0.0
    with pytest.raises(ValueError, match="min_score"):
        replace(cfg.measurement, min_score=1.5)
