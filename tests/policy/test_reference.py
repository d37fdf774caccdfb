"""Plan features (policy/reference.py): what a specialist reads of its track's plan, how the
exported policy carries it, and the training config's checks."""

from __future__ import annotations

import json
from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pytest

from icarus_vision.policy.config import SPECIALIST, config_from_dict
from icarus_vision.policy.export import export_sb3_policy, load_init_actor, load_policy
from icarus_vision.policy.features import FEATURES_V1, obs_to_features
from icarus_vision.policy.reference import AHEAD_S, REFERENCE_DIM, PlanReference
from icarus_vision.sim.track import Gate, Track


def straight_plan(track: Track, n: int = 10, speed: float = 4.0):
    """A plan-shaped object flying along x at ``speed`` through gates on the x axis, level, at half
    thrust, ``n`` nodes per passage."""
    xs = [0.0, *(g.pos[0] for g in track.passages)]
    pos = np.concatenate(
        [np.linspace(a, b, n + 1)[:-1] for a, b in zip(xs[:-1], xs[1:], strict=True)]
    )
    pos = np.append(pos, xs[-1])
    k = len(pos)
    p = np.column_stack([pos, np.zeros(k), np.full(k, 2.0)])
    return SimpleNamespace(
        t=pos / speed, pos=p, vel=np.tile([speed, 0.0, 0.0], (k, 1)),
        quat=np.tile([0.0, 0.0, 0.0, 1.0], (k, 1)), thrust=np.full(k, 5.0),
        gate_nodes=np.arange(1, len(xs)) * n,
    )  # fmt: skip


def obs_at(pos, gate, gate_yaw, yaw=0.0):
    """Extended observations (N, 21) of drones at ``pos`` flying to ``gate`` (passage ``gate_yaw``)."""
    pos = np.atleast_2d(np.asarray(pos, float))
    n = len(pos)
    obs = np.zeros((n, 21))
    obs[:, 0:3] = pos
    obs[:, 8] = yaw
    obs[:, 12:15] = np.asarray(gate, float) - pos
    obs[:, 15:17] = [np.cos(gate_yaw), np.sin(gate_yaw)]
    return obs


def test_features_read_the_plan_at_the_nearest_node_of_the_gates_segment():
    track = Track(name="line", gates=(Gate(pos=(5.0, 0.0, 2.0)), Gate(pos=(10.0, 0.0, 2.0))))
    ref = PlanReference.from_plan(straight_plan(track), track, thrust_max=10.0)
    assert ref.pos.shape == (2, 11, 3) and ref.gate_dir.shape == (2, 2)
    # 0.3 m right of the plan at x = 2 (the node there), flying to gate 0, drone yawed 90° left:
    obs = obs_at([[2.0, -0.3, 2.0]], (5.0, 0.0, 2.0), 0.0, yaw=np.pi / 2)
    f = ref.features(obs)[0]
    assert f.shape == (REFERENCE_DIM,)
    np.testing.assert_allclose(f[0:3], [0.3, 0.0, 0.0], atol=1e-6)  # the node is to its front
    np.testing.assert_allclose(f[3:6], [0.0, -4.0 / 5.0, 0.0], atol=1e-6)  # plan flies to its right
    np.testing.assert_allclose(f[6:9], f[3:6], atol=1e-6)  # constant speed AHEAD_S on
    np.testing.assert_allclose(f[9:12], [0.0, 0.0, 1.0], atol=1e-6)  # level
    assert f[12] == pytest.approx(0.5)
    # Past gate 0 the drone flies to gate 1: the node is on the second segment, behind no more.
    s, k = ref.nearest(obs_at([[5.5, 0.0, 2.0]], (10.0, 0.0, 2.0), 0.0))
    assert (s[0], ref.pos[s[0], k[0], 0]) == (1, 5.5)


def test_a_gate_flown_both_ways_picks_the_passage_by_its_direction():
    """A hairpin: one gate passed outward, then back; the passage direction picks the segment."""
    out_and_back = (Gate(pos=(5.0, 0.0, 2.0)), Gate(pos=(10.0, 0.0, 2.0)),
                    Gate(pos=(5.0, 0.0, 2.0), yaw_deg=180.0))  # fmt: skip
    track = Track(name="hairpin-ish", gates=out_and_back)
    plan = straight_plan(Track(name="x", gates=out_and_back[:2]))  # 0 -> 5 -> 10 ...
    back = np.linspace(10.0, 5.0, 11)[1:]  # ... and 10 -> 5 flying -x
    pos = np.vstack([plan.pos, np.column_stack([back, np.zeros(10), np.full(10, 2.0)])])
    vel = np.vstack([plan.vel, np.tile([-4.0, 0.0, 0.0], (10, 1))])
    plan = SimpleNamespace(
        t=np.arange(len(pos)) * 0.125, pos=pos, vel=vel, quat=np.tile([0, 0, 0, 1.0], (len(pos), 1)),
        thrust=np.full(len(pos), 5.0), gate_nodes=np.array([10, 20, 30]),
    )  # fmt: skip
    ref = PlanReference.from_plan(plan, track, thrust_max=10.0)
    out = ref.features(obs_at([[4.0, 0.0, 2.0]], (5.0, 0.0, 2.0), 0.0))[0]
    home = ref.features(obs_at([[6.0, 0.0, 2.0]], (5.0, 0.0, 2.0), np.pi))[0]
    assert out[3] == pytest.approx(4.0 / 5.0) and home[3] == pytest.approx(-4.0 / 5.0)


def test_reference_checks_its_arrays_and_the_observation():
    track = Track(name="line", gates=(Gate(pos=(5.0, 0.0, 2.0)),))
    plan = straight_plan(track)
    ref = PlanReference.from_plan(plan, track, thrust_max=10.0)
    with pytest.raises(ValueError, match="extended or racing"):
        ref.features(np.zeros((1, 15)))
    with pytest.raises(ValueError, match="plan of 1 passages for a track of 2"):
        PlanReference.from_plan(plan, replace(track, laps=2), thrust_max=10.0)
    bad = ref.tensors()
    bad["ref.vel"] = bad["ref.vel"][:, :3]
    with pytest.raises(ValueError, match="vel must be finite of shape"):
        PlanReference.from_tensors(bad)
    del bad["ref.thrust"]
    with pytest.raises(ValueError, match="missing tensors thrust"):
        PlanReference.from_tensors(bad)
    assert np.isclose(AHEAD_S, 0.3)


def small_model(reference):
    from stable_baselines3 import PPO

    from icarus_vision.policy.features import FeatureVecEnv
    from icarus_vision.sim.vec_env import BatchedRacingVecEnv

    env = BatchedRacingVecEnv(2, track="single-gate", observation="extended")
    env = FeatureVecEnv(env, FEATURES_V1, reference)
    return PPO("MlpPolicy", env, n_steps=8, batch_size=16, device="cpu", seed=0)


def test_exported_specialist_carries_its_plan_and_starts_from_a_policy_without(tmp_path):
    track = Track(name="line", gates=(Gate(pos=(5.0, 0.0, 2.0)),))
    ref = PlanReference.from_plan(straight_plan(track), track, thrust_max=10.0)
    model = small_model(ref)
    path = export_sb3_policy(model, tmp_path / "spec", "extended", {"name": "s"}, FEATURES_V1, ref)
    pol = load_policy(path, expect_obs_dim=21)
    assert (
        pol.reference is not None
        and json.loads((tmp_path / "spec.json").read_text())["reference"] == "plan"
    )
    obs = obs_at(np.random.default_rng(0).normal([2, 0, 2], 1.0, (6, 3)), (5.0, 0.0, 2.0), 0.0)
    x = np.concatenate([obs_to_features(obs), ref.features(obs)], axis=1)
    want, _ = model.predict(x, deterministic=True)
    np.testing.assert_allclose(pol.act(obs), want, atol=1e-5)

    # A policy without plan features starts a run with them and flies as before (zero weights).
    plain = small_model(None)
    plain_path = export_sb3_policy(plain, tmp_path / "plain", "extended")
    fresh = small_model(ref)
    load_init_actor(fresh, str(plain_path), "extended", FEATURES_V1, reference=True)
    fresh_path = export_sb3_policy(fresh, tmp_path / "fresh", "extended", None, FEATURES_V1, ref)
    np.testing.assert_allclose(
        load_policy(fresh_path).act(obs), load_policy(plain_path).act(obs), atol=1e-6
    )
    # ... but one with them continues only a run with them.
    with pytest.raises(ValueError, match="continue it with reference = 'plan'"):
        load_init_actor(small_model(None), str(path), "extended", FEATURES_V1, reference=False)

    # A description that names a plan its tensors lack is refused, naming the file.
    (tmp_path / "plain.json").write_text(
        json.dumps({**json.loads((tmp_path / "plain.json").read_text()), "reference": "plan"})
    )
    with pytest.raises(ValueError, match="plain.safetensors: plan reference: missing tensors"):
        load_policy(plain_path)


def test_train_config_reference_needs_a_track_and_a_gate_direction():
    with pytest.raises(ValueError, match="reference 'plan' needs a fixed track"):
        config_from_dict({"preset": "specialist", "reference": "plan"})
    with pytest.raises(ValueError, match="reference is out of range"):
        config_from_dict({"preset": "specialist", "track": "split-s", "reference": "path"})
    with pytest.raises(ValueError, match="reference 'plan' needs"):
        config_from_dict(
            {"preset": "specialist", "track": "split-s", "reference": "plan",
             "observation": "basic"}
        )  # fmt: skip
    assert replace(SPECIALIST, track="split-s", reference="plan").reference == "plan"


def test_specialist_with_plan_features_trains_and_exports_its_plan(tmp_path, monkeypatch):
    from icarus_vision.policy.config import PPOConfig
    from icarus_vision.policy.train import train_policy

    monkeypatch.chdir(tmp_path)  # the plan is solved and cached under ./runs/plans
    cfg = replace(
        SPECIALIST, track="single-gate", reference="plan",
        ppo=PPOConfig(num_envs=16, n_steps=32, batch_size=256, n_epochs=1, net_arch=(64, 64)),
        init_critic_steps=0, checkpoint_every=512, eval_every=512, eval_episodes=4,
    )  # fmt: skip
    result = train_policy(cfg, tmp_path / "run", seed=0, timesteps=1024, verbose=0)
    assert list((tmp_path / "runs" / "plans").glob("single-gate-*.npz"))
    for path in (result.policy_path, tmp_path / "run" / "best.safetensors"):
        pol = load_policy(path)
        assert pol.reference is not None and pol.reference.pos.shape[0] == 1
        obs = obs_at([[0.0, 0.0, 1.0]], (5.0, 0.0, 2.0), 0.0)
        assert pol.act(obs).shape == (1, 4)


def test_flying_a_plan_reading_policy_on_another_track_warns(tmp_path):
    track = Track(name="line", gates=(Gate(pos=(5.0, 0.0, 2.0)),))
    ref = PlanReference.from_plan(straight_plan(track), track, thrust_max=10.0)
    pol = load_policy(
        export_sb3_policy(small_model(ref), tmp_path / "s", "extended", None, FEATURES_V1, ref)
    )
    moved = Track(name="moved", gates=(Gate(pos=(5.0, 3.0, 2.0)),))
    with pytest.warns(UserWarning, match="reads the plan of the track it was trained on"):
        pol.check_track(moved)
    with pytest.warns(UserWarning, match="another track"):
        pol.check_track(None, "this evaluation")
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        pol.check_track(track.with_laps(2))  # its own track, any laps: no warning
