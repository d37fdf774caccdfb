"""The racing additions: out-of-view perception, shipped-policy resolution, fine-tuning from an
exported actor, specialists and the layout-difficulty curriculum."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from stable_baselines3 import PPO

from icarus_vision.policy.callbacks import CurriculumCallback
from icarus_vision.policy.config import (
    SPECIALIST,
    CurriculumConfig,
    PPOConfig,
    config_from_dict,
)
from icarus_vision.policy.export import export_sb3_policy, load_init_actor, load_policy
from icarus_vision.policy.features import FEATURES_V1, FEATURES_V2, obs_to_features
from icarus_vision.policy.perception_noise import ErrorModel, PerceptionNoise, gate_in_view
from icarus_vision.policy.pilots import (
    auto_policy_name,
    resolve_policy,
    shipped_policies,
    shipped_policy_path,
)
from icarus_vision.policy.train import make_train_env, run_features, train_policy
from icarus_vision.sim.builtin import builtin_track
from icarus_vision.sim.config import RACING_LINE_REWARD
from icarus_vision.sim.quad import CameraParams


def _obs(rpy, gate):
    obs = np.zeros((len(gate), 21), np.float32)
    obs[:, 6:9] = rpy
    obs[:, 12:15] = gate
    return obs


def test_gate_in_view_follows_the_camera():
    cam = CameraParams()  # 90° horizontal field of view, 20° uptilt
    gates = np.array([[5.0, 0, 0], [5.0, 4.0, 0], [-5.0, 0, 0], [5.0, 0, -4.0], [5.0, 6.0, 0]])
    assert gate_in_view(_obs(0.0, gates), cam).tolist() == [True, True, False, False, False]
    yawed = _obs(np.array([0.0, 0.0, np.pi / 2]), np.array([[0.0, 5.0, 0.0], [5.0, 0.0, 0.0]]))
    assert gate_in_view(yawed, cam).tolist() == [True, False]


def test_out_of_view_gates_are_never_seen():
    model = ErrorModel((0.0, 30.0), (0.5, 0.5), (0.0, 0.0))  # always detected when in view
    noise = PerceptionNoise(model, 2, seed=0, camera=CameraParams())
    first = noise.apply(_obs(0.0, np.array([[5.0, 0, 0], [5.0, 0, 0]])), np.ones(2, bool))
    moved = _obs(0.0, np.array([[5.0, 1.0, 0], [-5.0, 0.0, 0]]))
    moved[:, 0:3] = [[0.0, -1.0, 0.0], [10.0, 0.0, 0.0]]  # the drones moved; the gate stayed
    out = noise.apply(moved, np.zeros(2, bool))
    held = out[:, 12:15] + moved[:, 0:3]  # world estimates
    assert not np.allclose(held[0], first[0, 12:15])  # in view: a fresh measurement
    assert held[1] == pytest.approx(first[1, 12:15], abs=1e-5)  # behind the drone: held


def test_a_new_gate_starts_from_the_maps_error_and_keeps_it_until_seen():
    """With a map error, a new target gate's first estimate is off by a uniform draw within ±
    the error per axis (not the detector's σ), and a gate outside the view keeps that error."""
    model = ErrorModel((0.0, 30.0), (0.0, 0.0), (0.0, 0.0))  # detections are exact
    n = 4000
    gates = np.tile([[-5.0, 0.0, 0.0]], (n, 1))  # behind the drones: never seen
    noise = PerceptionNoise(model, n, seed=0, camera=CameraParams(), map_error_m=0.3)
    first = noise.apply(_obs(0.0, gates), np.ones(n, bool))
    err = first[:, 12:15] - gates
    assert np.abs(err).max() <= 0.3 + 1e-6 and np.abs(err).max() > 0.29
    assert err.std(axis=0) == pytest.approx(np.full(3, 0.3 / np.sqrt(3)), rel=0.05)
    later = noise.apply(_obs(0.0, gates), np.zeros(n, bool))
    assert later[:, 12:15] == pytest.approx(first[:, 12:15], abs=1e-6)  # held: still unseen
    exact = PerceptionNoise(model, n, seed=0, camera=CameraParams())
    assert exact.apply(_obs(0.0, gates), np.ones(n, bool))[:, 12:15] == pytest.approx(gates)
    with pytest.raises(ValueError, match="perception.map_error_m"):
        config_from_dict({"perception": {"map_error_m": -0.1}})


def test_a_gates_bias_holds_for_its_whole_approach_and_is_drawn_again_for_the_next():
    """With ``bias_m`` every detection of one target gate is off the same way (the white noise
    on top unchanged: the same draws as without it); a new gate draws a new bias."""
    model = ErrorModel((0.0, 30.0), (0.01, 0.01), (0.0, 0.0))  # 1 cm white noise, no misses
    n = 4000
    ahead = np.tile([[5.0, 0.0, 0.0]], (n, 1))  # in front of the camera: seen every frame
    biased = PerceptionNoise(model, n, seed=0, camera=CameraParams(), bias_m=0.1)
    plain = PerceptionNoise(model, n, seed=0, camera=CameraParams())
    offsets = []
    for step in range(3):
        new = np.full(n, step == 0)
        b = biased.apply(_obs(0.0, ahead), new)[:, 12:15]
        p = plain.apply(_obs(0.0, ahead), new)[:, 12:15]
        offsets.append(b - p)
    assert offsets[1] == pytest.approx(offsets[0], abs=1e-5)  # the same bias frame after frame
    assert offsets[2] == pytest.approx(offsets[0], abs=1e-5)
    assert offsets[0].std(axis=0) == pytest.approx(np.full(3, 0.1), rel=0.05)
    moved = ahead + [0.0, 2.0, 0.0]  # the next gate: a new draw
    b = biased.apply(_obs(0.0, moved), np.zeros(n, bool))[:, 12:15]
    p = plain.apply(_obs(0.0, moved), np.zeros(n, bool))[:, 12:15]
    assert np.abs((b - p) - offsets[0]).mean() > 0.05
    with pytest.raises(ValueError, match="perception.bias_m"):
        config_from_dict({"perception": {"bias_m": -0.1}})


def test_only_the_bias_share_of_the_drones_flies_with_a_bias():
    """``bias_share`` gives the per-gate bias to the first share of the batch only; the others
    see exactly what they would without a bias."""
    model = ErrorModel((0.0, 30.0), (0.01, 0.01), (0.0, 0.0))
    n = 4000
    ahead = np.tile([[5.0, 0.0, 0.0]], (n, 1))
    half = PerceptionNoise(model, n, seed=0, camera=CameraParams(), bias_m=0.1, bias_share=0.25)
    plain = PerceptionNoise(model, n, seed=0, camera=CameraParams())
    new = np.ones(n, bool)
    offset = (
        half.apply(_obs(0.0, ahead), new)[:, 12:15] - plain.apply(_obs(0.0, ahead), new)[:, 12:15]
    )
    assert offset[: n // 4].std(axis=0) == pytest.approx(np.full(3, 0.1), rel=0.1)
    assert offset[n // 4 :] == pytest.approx(np.zeros((n - n // 4, 3)), abs=1e-6)
    with pytest.raises(ValueError, match="perception.bias_share"):
        config_from_dict({"perception": {"bias_share": 1.5}})


def test_the_maps_heading_and_gate_after_are_off_until_the_gate_is_seen():
    """With a map heading error, a new target gate's passage direction is turned within ± the
    error while unseen and true once seen; the gate after is off by ± the map error throughout;
    the position draws are those of a run without it (a stream of their own)."""
    model = ErrorModel((0.0, 30.0), (0.0, 0.0), (0.0, 0.0))  # detections are exact
    n = 2000
    obs = _obs(0.0, np.tile([[-5.0, 0.0, 0.0]], (n, 1)))  # behind: unseen
    obs[:, 15:18] = [1.0, 0.0, 0.0]
    obs[:, 18:21] = [-9.0, 2.0, 0.0]
    noise = PerceptionNoise(model, n, 0, CameraParams(), map_error_m=0.3, map_yaw_error_deg=10.0)
    first = noise.apply(obs, np.ones(n, bool))
    yaw = np.degrees(np.arctan2(first[:, 16], first[:, 15]))
    assert np.abs(yaw).max() <= 10.0 + 1e-4 and np.abs(yaw).max() > 9.5
    assert np.linalg.norm(first[:, 15:18], axis=1) == pytest.approx(np.ones(n), abs=1e-6)
    after = first[:, 18:21] - obs[:, 18:21]
    assert np.abs(after).max() <= 0.3 + 1e-6 and np.abs(after).max() > 0.29
    plain = PerceptionNoise(model, n, 0, CameraParams(), map_error_m=0.3)
    assert plain.apply(obs, np.ones(n, bool))[:, 12:15] == pytest.approx(first[:, 12:15])
    ahead = obs.copy()
    ahead[:, 12:15] = [5.0, 0.0, 0.0]  # the same gate, now in view (the drones turned round)
    ahead[:, 0:3] = [-10.0, 0.0, 0.0]
    seen = noise.apply(ahead, np.zeros(n, bool))
    assert seen[:, 15:18] == pytest.approx(ahead[:, 15:18], abs=1e-6)  # seen: the true heading
    assert seen[:, 18:21] - ahead[:, 18:21] == pytest.approx(after, abs=1e-5)  # the map's still
    with pytest.raises(ValueError, match="perception.map_yaw_error_deg"):
        config_from_dict({"perception": {"map_yaw_error_deg": -1.0}})


def test_only_the_map_share_of_the_drones_fly_with_the_maps_errors():
    """map_share 0.25: the first quarter of the batch starts each gate from the map's error (as
    with share 1, the same draws), the rest from an ordinary (here exact) detection."""
    model = ErrorModel((0.0, 30.0), (0.0, 0.0), (0.0, 0.0))  # detections are exact
    n = 400
    obs = _obs(0.0, np.tile([[-5.0, 0.0, 0.0]], (n, 1)))  # behind: unseen
    obs[:, 15:18] = [1.0, 0.0, 0.0]
    obs[:, 18:21] = [-9.0, 2.0, 0.0]
    kw = {"map_error_m": 0.3, "map_yaw_error_deg": 10.0}
    every = PerceptionNoise(model, n, 0, CameraParams(), **kw).apply(obs, np.ones(n, bool))
    part = PerceptionNoise(model, n, 0, CameraParams(), **kw, map_share=0.25)
    some = part.apply(obs, np.ones(n, bool))
    assert some[:100] == pytest.approx(every[:100])
    assert some[100:] == pytest.approx(obs[100:])
    assert np.abs(some[:100, 12:21] - obs[:100, 12:21]).max() > 0.2
    with pytest.raises(ValueError, match="perception.map_share"):
        config_from_dict({"perception": {"map_share": 1.5}})


def test_auto_picks_a_shipped_specialist_only_for_its_own_layout():
    assert "default" in shipped_policies()
    for name in ("single-gate", "ten-gates"):
        if f"{name}-specialist" not in shipped_policies():
            assert auto_policy_name(builtin_track(name)) == "default"
    assert auto_policy_name(None) == "default"
    for spec in [s for s in shipped_policies() if s.endswith("-specialist")]:
        track = builtin_track(spec.removesuffix("-specialist"))
        assert auto_policy_name(track) == spec
        assert auto_policy_name(track.with_laps(3)) == spec
        g0 = track.gates[0]
        shifted = replace(g0, pos=(g0.pos[0] + 0.5, g0.pos[1], g0.pos[2]))
        moved = replace(track, gates=(shifted, *track.gates[1:]), bounds_min=None, bounds_max=None)
        assert auto_policy_name(moved) == "default"
        assert resolve_policy("auto", track=track).name == spec
    assert resolve_policy("auto", track=builtin_track("single-gate")).name in shipped_policies()
    assert resolve_policy("default").name == "default"


def test_shipped_policies_load_without_pickles():
    for name in shipped_policies():
        path = shipped_policy_path(name)
        assert path.read_bytes()[:8] != b"\x80\x04\x95"  # not a pickle
        json.loads(path.with_suffix(".json").read_text())
        pol = load_policy(path)
        assert pol.act(np.zeros(pol.obs_dim, np.float32)).shape == (4,)


def _tiny_ppo(observation: str = "extended", net_arch=(64, 64), features: str = "v1"):
    """An untrained PPO on a 4-drone specialist training env with ``observation``."""
    cfg = replace(
        SPECIALIST, observation=observation, features=features,
        ppo=replace(SPECIALIST.ppo, num_envs=4, batch_size=64),
    )  # fmt: skip
    env = make_train_env(cfg, 4, 3, seed=0)
    kwargs = {"net_arch": list(net_arch)}
    return PPO("MlpPolicy", env, policy_kwargs=kwargs, device="cpu", n_steps=8, batch_size=32)


def test_init_copies_the_exported_actor_and_refuses_mismatches():
    model = _tiny_ppo()
    policy = load_init_actor(model, "racing", "extended")
    obs = np.random.default_rng(0).normal(size=(16, 21)).astype(np.float32)
    mean, _ = model.predict(obs_to_features(obs), deterministic=True)
    assert np.clip(mean, -1, 1) == pytest.approx(policy.act(obs), abs=1e-5)
    small = _tiny_ppo(net_arch=(32,))
    with pytest.raises(ValueError, match="do not match"):
        load_init_actor(small, "racing", "extended")
    with pytest.raises(ValueError, match="larger than this run's basic"):
        load_init_actor(model, "racing", "basic")


def test_init_widens_a_smaller_observation_with_zero_weights():
    """A shipped (extended, v1) generalist fine-tuned on the racing observation flies as before,
    whatever the new entries say, until training gives them weight."""
    model = _tiny_ppo("racing")
    assert model.observation_space.shape == (24,)
    policy = load_init_actor(model, "racing", "racing")
    assert policy.observation == "extended"
    obs = np.random.default_rng(1).normal(size=(16, 25)).astype(np.float32)
    obs[:, 21] = np.random.default_rng(2).uniform(0.8, 1.5, 16)
    mean, _ = model.predict(obs_to_features(obs), deterministic=True)
    assert np.clip(mean, -1, 1) == pytest.approx(policy.act(obs[:, :21]), abs=1e-5)
    w = model.policy.mlp_extractor.policy_net[0].weight.detach().numpy()
    assert w.shape == (64, 24) and not w[:, 21:].any()


def test_init_widens_the_hidden_layers_without_changing_the_actions():
    """A wider network (same depth) starts from the exported actor: the new units have zero
    outgoing weight, so the actions are the exported policy's; a narrower one is refused."""
    model = _tiny_ppo("racing", net_arch=(96, 80))
    policy = load_init_actor(model, "racing", "racing")
    obs = np.random.default_rng(3).normal(size=(16, 25)).astype(np.float32)
    mean, _ = model.predict(obs_to_features(obs), deterministic=True)
    assert np.clip(mean, -1, 1) == pytest.approx(policy.act(obs[:, :21]), abs=1e-5)
    hidden = model.policy.mlp_extractor.policy_net[2].weight.detach().numpy()
    assert hidden.shape == (80, 96) and not hidden[:64, 64:].any() and hidden[64:].any()
    assert not model.policy.action_net.weight.detach().numpy()[:, 64:].any()
    with pytest.raises(ValueError, match="at least as wide"):
        load_init_actor(_tiny_ppo(net_arch=(64, 32)), "racing", "extended")


def test_init_starts_v2_features_from_a_v1_policy_and_exports_them(tmp_path):
    """A shipped v1 generalist (`racing`) starts a v2 run: zero weights for the gate-frame features, so
    it flies as before; the export says v2 and loads back to the same actions; a v2 policy is
    refused by a v1 run and by a larger observation (its features do not begin theirs)."""
    model = _tiny_ppo(features="v2")
    assert model.observation_space.shape == (29,)
    policy = load_init_actor(model, "racing", "extended", FEATURES_V2)
    obs = np.random.default_rng(5).normal(size=(16, 21)).astype(np.float32)
    mean, _ = model.predict(obs_to_features(obs, FEATURES_V2), deterministic=True)
    assert np.clip(mean, -1, 1) == pytest.approx(policy.act(obs), abs=1e-5)
    assert not model.policy.mlp_extractor.policy_net[0].weight.detach().numpy()[:, 21:].any()
    export_sb3_policy(model, tmp_path / "v2", "extended", {}, FEATURES_V2)
    back = load_policy(tmp_path / "v2")
    assert back.features == FEATURES_V2 and back.act(obs) == pytest.approx(
        policy.act(obs), abs=1e-5
    )
    with pytest.raises(ValueError, match="features = 'v2'"):
        load_init_actor(_tiny_ppo(), str(tmp_path / "v2"), "extended")
    with pytest.raises(ValueError, match="observation = 'extended'"):
        load_init_actor(
            _tiny_ppo("racing", features="v2"), str(tmp_path / "v2"), "racing", FEATURES_V2
        )
    racing = _tiny_ppo("racing", features="v2")  # a v1 policy's features begin v2 racing's
    assert load_init_actor(racing, "racing", "racing", FEATURES_V2).features != FEATURES_V2
    with pytest.raises(ValueError, match="features"):
        config_from_dict({"features": "v3"})


def test_a_run_reads_its_init_policys_features_unless_told():
    """`--init default` continues the shipped generalist with the features it reads (v2);
    a v1 policy, no policy, or the config's own choice gives those."""
    assert load_policy(shipped_policy_path("default")).features == FEATURES_V2
    assert run_features(SPECIALIST) == FEATURES_V2  # its init is "default"
    assert run_features(replace(SPECIALIST, init="racing")) == FEATURES_V1
    assert run_features(replace(SPECIALIST, init=None)) == FEATURES_V1
    assert run_features(replace(SPECIALIST, init="racing", features="v2")) == FEATURES_V2
    env = make_train_env(SPECIALIST, 2, 3, 0)
    assert env.observation_space.shape == (29,)


def test_difficulty_curriculum_config_is_validated():
    cfg = config_from_dict({"curriculum": {"stages": [3, 10], "difficulty": [0.2, 1.0]}})
    assert cfg.curriculum.difficulty_at(1) == 1.0
    with pytest.raises(ValueError, match="curriculum.difficulty"):
        config_from_dict({"curriculum": {"stages": [3, 10], "difficulty": [0.2]}})
    with pytest.raises(ValueError, match="curriculum.difficulty"):
        config_from_dict({"curriculum": {"stages": [3], "difficulty": [1.5]}})


def test_curriculum_counts_only_episodes_at_the_current_difficulty():
    cb = CurriculumCallback(
        CurriculumConfig(stages=(3, 3), difficulty=(0.2, 0.8), window=4, min_episodes=4), verbose=0
    )
    cb.venv = type("V", (), {"env_method": lambda self, *a, **k: None})()
    ok = {"gates_total": 3, "all_gates_passed": True, "crashed": False}
    for _ in range(4):
        cb.record({**ok, "difficulty": 0.8})  # old-stage episodes do not count
    assert cb.stage == 0
    promoted = [cb.record({**ok, "difficulty": 0.2}) for _ in range(4)]
    assert promoted[-1] and cb.stage == 1 and cb.difficulty == 0.8


def test_specialist_fine_tune_smoke(tmp_path):
    cfg = replace(
        SPECIALIST,
        track="hairpin",
        ppo=PPOConfig(
            num_envs=32,
            n_steps=32,
            batch_size=512,
            n_epochs=2,
            net_arch=(64, 64),
            log_std_init=-1.0,
        ),
        init_critic_steps=1024,
        checkpoint_every=2048,
        eval_every=2048,
        eval_episodes=8,
    )
    result = train_policy(cfg, tmp_path / "run", seed=0, timesteps=4096, verbose=0)
    assert result.num_gates == 3 and result.timesteps >= 4096
    pol = load_policy(result.policy_path)
    assert pol.observation == "extended"
    saved = json.loads((tmp_path / "run" / "config.json").read_text())
    assert saved["track"] == "hairpin" and saved["init"] == "default"
    with pytest.raises(ValueError, match="out of range"):
        config_from_dict({"init_critic_steps": -1})


@pytest.mark.parametrize("same", [False, True])
def test_evaluations_fly_the_same_layouts_when_asked(tmp_path, monkeypatch, same):
    import icarus_vision.policy.train as train_mod

    seeds = []
    real = train_mod.evaluate_model

    def spy(model, cfg, num_gates, episodes, seed, *rest):
        seeds.append(seed)
        return real(model, cfg, num_gates, episodes, seed, *rest)

    monkeypatch.setattr(train_mod, "evaluate_model", spy)
    cfg = replace(
        SPECIALIST, track="single-gate", eval_same_layouts=same, init_critic_steps=0,
        ppo=PPOConfig(num_envs=16, n_steps=32, batch_size=256, n_epochs=1, net_arch=(64, 64)),
        checkpoint_every=10**9, eval_every=512, eval_episodes=4,
    )  # fmt: skip
    train_policy(cfg, tmp_path / "run", seed=3, timesteps=2048, verbose=0)
    assert len(seeds) >= 3
    assert (len(set(seeds)) == 1) == same and seeds[0] == 10_003 + (0 if same else 512)


def test_time_cost_adds_to_the_presets_time_weight():
    assert SPECIALIST.time_cost == 2.0 and SPECIALIST.reward_config().time == -2.0
    assert replace(SPECIALIST, time_cost=0.0).reward_config() == RACING_LINE_REWARD
    with pytest.raises(ValueError, match="time_cost"):
        config_from_dict({"time_cost": -1.0})


def test_perception_cost_replaces_the_presets_weight():
    assert SPECIALIST.reward_config().perception == RACING_LINE_REWARD.perception == -0.05
    assert replace(SPECIALIST, perception_cost=0.5).reward_config().perception == -0.5
    with pytest.raises(ValueError, match="perception_cost"):
        config_from_dict({"perception_cost": -0.1})


def test_crash_cost_and_center_reward_replace_the_presets_weights():
    assert SPECIALIST.reward_config().crash == -10.0 and SPECIALIST.reward_config().center == 0.0
    r = replace(SPECIALIST, crash_cost=30.0, center_reward=5.0).reward_config()
    assert (r.crash, r.center) == (-30.0, 5.0)
    assert replace(SPECIALIST, align_reward=3.0).reward_config().align == 3.0
    assert SPECIALIST.reward_config().align == 0.0
    for key in ("crash_cost", "center_reward", "align_reward"):
        with pytest.raises(ValueError, match=key):
            config_from_dict({key: -1.0})


def test_plan_line_measures_progress_along_the_tracks_plan(tmp_path, monkeypatch):
    """The plan-line preset: racing-line with the path term for the line term; refused without a
    fixed track; its training env solves and caches the track's plan and flies against it (the
    reference runs from the start to the gate's plane)."""
    r = replace(SPECIALIST, track="split-s", reward="plan-line").reward_config()
    assert (r.line, r.path) == (0.0, 1.0)
    assert replace(r, line=1.0, path=0.0) == SPECIALIST.reward_config()
    with pytest.raises(ValueError, match="plan-line.*fixed track"):
        config_from_dict({"reward": "plan-line"})
    monkeypatch.chdir(tmp_path)  # the plan is cached under ./runs/plans
    cfg = replace(SPECIALIST, track="single-gate", reward="plan-line")
    env = make_train_env(cfg, num_envs=2, num_gates=1, seed=0)
    assert list((tmp_path / "runs" / "plans").glob("single-gate-*.npz"))
    base = env
    while not hasattr(base, "core"):  # under the perception noise and feature wrappers
        base = base.venv
    (ref,) = base.core.ref_path
    assert ref[0] == pytest.approx([0.0, 0.0, 0.2])  # single-gate's start
    assert ref[-1][0] == pytest.approx(5.0) and abs(ref[-1][1]) < 0.5  # its gate's plane
    assert base.core.ref_arc[0, -1] > 5.0
    env.reset()
    env.step(np.tile([0.8, 0.0, 0.0, 0.0], (2, 1)))  # the path term is computed, not refused


def test_plan_starts_train_from_the_tracks_plan(tmp_path, monkeypatch):
    """curriculum.plan_start: refused without a fixed track; the training env solves and caches
    the track's plan and starts that share of its episodes from the plan's states."""
    with pytest.raises(ValueError, match="plan_start needs a fixed track"):
        config_from_dict({"curriculum": {"plan_start": 0.5}})
    monkeypatch.chdir(tmp_path)  # the plan is cached under ./runs/plans
    cfg = replace(SPECIALIST, track="single-gate")
    env = make_train_env(cfg, num_envs=16, num_gates=1, seed=0, plan_start=0.5)
    assert list((tmp_path / "runs" / "plans").glob("single-gate-*.npz"))
    base = env
    while hasattr(base, "venv"):  # under the perception noise and feature wrappers
        base = base.venv
    assert base.core.plan_nodes is not None
    env.reset()
    assert 0 < base.core.replayed.sum() < 16  # some episodes started along the plan
    assert np.all(base.state.pos[base.core.replayed, 0] > 0.0)  # left the start for x = 5
    env.step(np.tile([0.8, 0.0, 0.0, 0.0], (16, 1)))


@pytest.mark.parametrize(
    "path", sorted(Path(__file__).parents[2].joinpath("configs").glob("policy-*.toml")), ids=str
)
def test_every_shipped_training_config_loads(path):
    """The configs the README and `make train-generalist` name are valid train-policy configs."""
    from icarus_vision.policy.config import load_train_config

    load_train_config(path)  # raises on an unknown key or a value out of range
