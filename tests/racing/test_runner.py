from __future__ import annotations

import json

import numpy as np
import pytest

from icarus_vision.racing.report import REPORT_FIELDS, validate_report
from icarus_vision.racing.runner import run_race
from icarus_vision.racing.video import write_video


def test_race_single_gate_oracle_report_has_every_field(backend):
    res = run_race("single-gate", backend=backend, seed=0, detector="oracle", policy="scripted")
    r = res.report
    validate_report(r)
    assert set(r) == set(REPORT_FIELDS)
    assert r["finished"] and r["gates_passed"] == r["gates_total"] == 1
    assert r["lap_times_s"] and r["total_time_s"] == r["lap_times_s"][0]
    assert r["detector"] == "oracle" and r["policy"] == "scripted" and r["backend"] == backend
    assert r["realtime_factor"] > 1 and r["perception"]["frames"] > 0
    # the oracle sees the true gate: no detection rate or estimation error to report
    assert r["perception"]["detection_rate"] is None
    assert r["perception"]["rel_gate_error_m"] == {"median": None, "p95": None}
    json.dumps(r, allow_nan=False)  # standard JSON, nulls where nothing applies
    assert res.pos.shape == (len(res.t), 3)


def test_laps_override_counts_passages():
    r = run_race(
        "single-gate", laps=2, backend="batched", detector="oracle", policy="scripted"
    ).report
    assert r["laps"] == 2 and r["gates_total"] == 2


def test_video_frames_are_written_and_decode(tmp_path):
    res = run_race(
        "single-gate", backend="batched", detector="oracle", policy="scripted", video=True
    )
    assert len(res.video) >= 30
    h, w, _ = res.video[0].shape
    write_video(tmp_path / "race.mp4", res.video, 30.0)
    import imageio.v2 as imageio

    reader = imageio.get_reader(tmp_path / "race.mp4")
    first = reader.get_data(0)
    n = sum(1 for _ in reader)
    reader.close()
    assert first.shape == (h, w, 3) and n == len(res.video)
    assert not list(tmp_path.glob(".race*"))  # no temporary file left behind


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"detector": "lidar"}, "lidar"),
        ({"backend": "ode"}, "unknown backend"),
        (
            {"policy": "missing_policy.safetensors"},
            "missing_policy.safetensors: policy file not found",
        ),
        ({"latency_frames": -1}, "latency_frames"),
        ({"randomize": True, "recipe": "gates-v9"}, "gates-v1, gates-v3"),
    ],
)
def test_bad_arguments(kwargs, match):
    with pytest.raises((ValueError, FileNotFoundError), match=match):
        run_race("single-gate", **{"detector": "oracle", "policy": "scripted", **kwargs})


def test_trajectory_starts_at_start():
    res = run_race("single-gate", backend="batched", detector="oracle", policy="scripted")
    np.testing.assert_allclose(res.pos[0], res.track.start_pos)


def test_race_with_the_shipped_cnn_and_policy_finishes():
    r = run_race("single-gate", seed=0).report  # defaults: cnn detector, shipped policy, pybullet
    assert r["detector"] == "cnn" and r["policy"] == "default"
    assert r["finished"], r
    p = r["perception"]
    assert p["frames"] > 10 and p["detection_rate"] > 0  # a 0.8 s flight, mostly climbing
    assert p["rel_gate_error_m"]["median"] < 0.5


def test_randomize_draws_the_worlds_look_from_the_recipe():
    """With --randomize the camera sees a world drawn from the recipe, once per race: the same
    seed, the same frames; another seed, another look; the shipped CNN flies a single gate in a
    gates-v1 world, and a gates-v3 one (halls, LEDs, lenses off: the quad's camera) renders."""
    kw = {"backend": "batched", "policy": "scripted", "video": True, "randomize": True}
    a = run_race("single-gate", seed=1, **kw)
    b = run_race("single-gate", seed=1, **kw)
    c = run_race("single-gate", seed=2, **kw)
    plain = run_race("single-gate", seed=1, **{**kw, "recipe": None})
    fpv = (slice(None), slice(0, 320))  # the video's left half is the camera
    np.testing.assert_array_equal(a.video[5][fpv], b.video[5][fpv])
    assert np.abs(a.video[5][fpv].astype(int) - c.video[5][fpv]).mean() > 10
    assert np.abs(a.video[5][fpv].astype(int) - plain.video[5][fpv]).mean() > 10
    r = run_race("single-gate", seed=4, randomize=True).report
    assert r["finished"] and r["perception"]["detection_rate"] > 0
    r = run_race("single-gate", seed=4, randomize=True, recipe="gates-v3").report
    assert r["perception"]["frames"] > 10


def test_open_loop_flies_the_oracles_flight_and_records_the_estimate():
    """Open loop: the pilot reads the truth, so the flight is the oracle's to the step, while the
    camera, detector and estimator run alongside and record their error each frame."""
    kw = {"policy": "default", "seed": 3, "randomize": True}
    truth = run_race("single-gate", detector="oracle", **kw)
    seen = run_race("single-gate", detector="opencv", open_loop=True, **kw)
    np.testing.assert_array_equal(seen.pos, truth.pos)
    rec = seen.loop
    assert (
        rec.frames > 10
        and len(rec.rel_err) == len(rec.gate_dist) == len(rec.target_ok) == rec.frames
    )
    assert all(rec.target_ok[:5]) and rec.gate_dist[0] > rec.gate_dist[5]  # flying at the gate
    assert seen.report["perception"]["detection_rate"] is not None


def test_lookahead_flies_the_race_and_says_so():
    """race --lookahead: the report names the filter; with the oracle the filter's model flies the
    true race, with a detector the race as vision knows it (odometry and the estimator's map)."""
    for detector in ("oracle", "opencv"):
        r = run_race("single-gate", detector=detector, seed=2, randomize=True, lookahead=True)
        assert r.report["policy"] == "default+lookahead"
        assert r.report["finished"], r.report
    with pytest.raises(ValueError, match="scripted"):
        run_race("single-gate", detector="oracle", policy="scripted", lookahead=True)
    from icarus_vision.policy.lookahead import racing

    r = run_race("single-gate", detector="oracle", seed=2, lookahead=racing())
    assert r.report["policy"] == "default+lookahead-race" and r.report["finished"]
    with pytest.raises(ValueError, match="lookahead"):
        run_race("single-gate", detector="oracle", lookahead="race")  # the config, not a name


def test_the_believed_race_puts_the_gates_where_vision_has_them():
    from icarus_vision.estimator import OdometryReading
    from icarus_vision.estimator.estimator import GateEstimator
    from icarus_vision.racing.loop import believed_race, odometry_state
    from icarus_vision.render.camera import Camera
    from icarus_vision.sim.config import EnvConfig
    from icarus_vision.sim.dynamics import QuadState
    from icarus_vision.sim.track import Gate, Track
    from icarus_vision.sim.vec_env import BatchedRacingVecEnv

    prior = Track("two", (Gate((6.0, 0.0, 2.0)), Gate((14.0, 1.0, 2.0), yaw_deg=10.0)))
    env = BatchedRacingVecEnv(1, EnvConfig(track=prior))
    env.seed(0)
    env.reset()
    env.core.g_pos[0, :2] += 0.3  # the real gates are off the map
    est = GateEstimator(Camera(), prior=prior)
    od = OdometryReading(
        0.0, np.array([0.0, 0.0, 2.0]), np.array([1.0, 0, 0]), np.array([0, 0, 0, 1.0]), np.zeros(3)
    )
    estimate = est.predict(od)
    pos, yaw = est.passage_map()
    np.testing.assert_allclose(pos, [[6.0, 0.0, 2.0], [14.0, 1.0, 2.0]])
    np.testing.assert_allclose(yaw, [0.0, np.radians(10.0)], atol=1e-9)
    belief = believed_race(env.core, est, estimate, od, prior)
    np.testing.assert_allclose(belief.g_pos[0, 0], od.pos + estimate.rel_world)
    np.testing.assert_allclose(belief.g_pos[0, 1], [14.0, 1.0, 2.0])
    assert belief.g_cos[0, 1] == pytest.approx(np.cos(np.radians(10.0)))
    np.testing.assert_allclose(env.core.g_pos[0, 1], [14.3, 1.3, 2.3])  # the race is untouched
    state = odometry_state(od, QuadState.zeros(1))
    np.testing.assert_array_equal(state.vel[0], [1.0, 0, 0])
