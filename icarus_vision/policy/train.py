"""PPO training on the batched backend: curriculum, randomisation, perception noise, checkpoints.

Output folder layout (``out``):

    config.json                 the resolved TrainConfig
    tb/                         TensorBoard logs (SB3's, plus curriculum/* and reward terms)
    checkpoints/last.zip        resumable SB3 checkpoint (written atomically), last_state.json beside it
    best.safetensors/.json      exported policy with the best evaluation (stage, then success
                                less LAP_WEIGHT × median lap per gate)
    policy.safetensors/.json    exported final policy
    evaluated/STEPS.*           every evaluated policy, exported, its evaluation in its meta
    metrics.json                wall-clock curve: timesteps, stage, success rate, mean return

Ctrl-C saves ``checkpoints/last.zip`` and re-raises; ``resume=True`` continues from it with the
step count and curriculum stage intact.
"""

from __future__ import annotations

import json
import shutil
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from icarus_vision.fileio import atomic_path, atomic_write_json
from icarus_vision.policy.callbacks import (
    Anneal,
    CriticWarmup,
    CurriculumCallback,
    MetricsCallback,
    RunningAdvantageNorm,
    episode_success,
)
from icarus_vision.policy.config import (
    CurriculumConfig,
    TrainConfig,
    config_differences,
    config_to_dict,
    load_run_config,
)
from icarus_vision.policy.critic import AsymmetricActorCriticPolicy, PrivilegedVecEnv
from icarus_vision.policy.export import ExportedPolicy, export_sb3_policy, load_init_actor
from icarus_vision.policy.features import FEATURES_V1, FEATURES_VERSIONS, FeatureVecEnv
from icarus_vision.policy.perception_noise import ErrorModel, PerceptionNoiseVecEnv
from icarus_vision.policy.reference import PlanReference
from icarus_vision.sim.builtin import resolve_track
from icarus_vision.sim.config import EnvConfig
from icarus_vision.sim.quad import QuadParams, load_quad
from icarus_vision.sim.vec_env import BatchedRacingVecEnv


@dataclass
class TrainResult:
    out: Path
    timesteps: int
    stage: int
    num_gates: int
    best_score: float
    policy_path: Path


def curriculum_of(cfg: TrainConfig) -> CurriculumConfig:
    """The curriculum a run follows: the config's, or one stage (the whole track) for a specialist."""
    if cfg.track is None:
        return cfg.curriculum
    n = len(resolve_track(cfg.track).gates)
    return replace(cfg.curriculum, stages=(n,), difficulty=None)


def run_features(cfg: TrainConfig) -> str:
    """The feature transform a run trains: the config's, else its ``init`` policy's, else v1."""
    if cfg.features is not None:
        return FEATURES_VERSIONS[cfg.features]
    if cfg.init is not None:
        from icarus_vision.policy.pilots import resolve_policy

        policy = resolve_policy(cfg.init)
        if isinstance(policy, ExportedPolicy):
            return policy.features
    return FEATURES_V1


def train_quad(cfg: TrainConfig) -> QuadParams:
    """The quadrotor ``cfg`` trains for: its ``quad`` file, or the built-in racer-500g."""
    return QuadParams() if cfg.quad is None else load_quad(cfg.quad)


def make_train_env(
    cfg: TrainConfig,
    num_envs: int,
    num_gates: int,
    seed: int,
    difficulty: float | None = None,
    features: str | None = None,
    layout_replay: float = 0.0,
    quad: QuadParams | None = None,
    crash_replay: float = 0.0,
    plan_start: float = 0.0,
):
    """The training VecEnv stack: batched drones -> perception noise -> policy features
    (-> the privileged critic's block, with ``cfg.privileged_critic``).

    Random tracks of ``num_gates`` gates at layout ``difficulty`` (None: classic layouts), or the
    config's fixed ``track``; ``features``: the transform (None: ``run_features(cfg)``);
    ``layout_replay``: the chance an episode re-flies a failed layout (training only); ``quad``:
    the config's quadrotor when already loaded (None: ``train_quad(cfg)`` reads it);
    ``crash_replay``: the chance an episode starts shortly before an earlier crash, ``plan_start``
    one from a state of the fixed track's time-optimal plan (both training only).
    """
    track = None if cfg.track is None else resolve_track(cfg.track)
    env_cfg = EnvConfig(
        track=track,
        quad=quad or train_quad(cfg),
        random_tracks=track is None,
        num_gates=num_gates,
        layout_difficulty=difficulty if track is None else None,
        layout_replay=layout_replay if track is None else 0.0,
        crash_replay=crash_replay,
        plan_start=plan_start,
        randomization=cfg.randomization,
        reward=cfg.reward_config(),
        observation=cfg.observation,
        max_episode_s=cfg.max_episode_s,
    )
    venv = BatchedRacingVecEnv(num_envs, env_cfg)
    reference = None
    if env_cfg.reward.path or plan_start > 0 or cfg.reference is not None:
        from icarus_vision.planning.planner import plan

        result = plan(track, env_cfg.quad)  # solved and cached when missing
        if env_cfg.reward.path:
            venv.core.set_reference(result.passage_paths())
        if plan_start > 0:
            venv.core.set_plan(result)
        if cfg.reference is not None:
            reference = PlanReference.from_plan(result, track, env_cfg.quad.thrust_max)
    venv.seed(seed)
    if cfg.perception.enabled:
        camera = env_cfg.quad.camera if cfg.perception.out_of_view else None
        model = ErrorModel.from_config(cfg.perception)
        venv = PerceptionNoiseVecEnv(
            venv, model, seed=seed + 7919, camera=camera, map_error_m=cfg.perception.map_error_m,
            map_yaw_error_deg=cfg.perception.map_yaw_error_deg, map_share=cfg.perception.map_share,
            bias_m=cfg.perception.bias_m, bias_share=cfg.perception.bias_share,
        )  # fmt: skip
    features = features or run_features(cfg)
    venv = FeatureVecEnv(venv, features, reference)
    return PrivilegedVecEnv(venv, features) if cfg.privileged_critic else venv


def _feature_env(venv) -> FeatureVecEnv:
    """The ``FeatureVecEnv`` in a training stack (``make_train_env``)."""
    while not isinstance(venv, FeatureVecEnv):
        venv = venv.venv
    return venv


LAP_WEIGHT = 0.1
"""Weight of the median lap per gate (s) against the success rate when choosing the best model:
a tenth of a second per gate is worth one point of success."""


@dataclass
class Evaluation:
    """A deterministic evaluation: success rate and the median time per gate of the successes."""

    success: float
    lap_per_gate_s: float | None

    @property
    def score(self) -> float:
        """Success rate less ``LAP_WEIGHT`` × median lap per gate (1 s per gate with no success)."""
        lap = 1.0 if self.lap_per_gate_s is None else self.lap_per_gate_s
        return self.success - LAP_WEIGHT * lap


def evaluate_model(
    model,
    cfg: TrainConfig,
    num_gates: int,
    episodes: int,
    seed: int,
    difficulty: float | None = None,
    features: str | None = None,
    quad: QuadParams | None = None,
) -> Evaluation:
    """The deterministic policy over ``episodes`` tracks (one per drone); ``quad``: the
    config's quadrotor when already loaded."""
    env = make_train_env(cfg, episodes, num_gates, seed, difficulty, features, quad=quad)
    obs = env.reset()
    result: list[bool | None] = [None] * episodes
    per_gate: list[float] = []
    while any(r is None for r in result):
        actions, _ = model.predict(obs, deterministic=True)
        obs, _, done, infos = env.step(actions)
        for i in np.flatnonzero(done):
            if result[i] is None:
                result[i] = episode_success(infos[i])
                if result[i]:
                    per_gate.append(infos[i]["time"] / infos[i]["gates_total"])
    lap = float(np.median(per_gate)) if per_gate else None
    return Evaluation(float(np.mean(result)), lap)


def _save_checkpoint(model, ckpt_dir: Path, state: dict) -> None:
    with atomic_path(ckpt_dir / "last.zip", suffix=".zip") as tmp:
        model.save(tmp)
    atomic_write_json(ckpt_dir / "last_state.json", state)


def train_policy(
    cfg: TrainConfig,
    out: str | Path,
    *,
    seed: int = 0,
    resume: bool = False,
    timesteps: int | None = None,
    progress=None,
    verbose: int = 1,
    max_wall_s: float | None = None,
    callbacks=None,
) -> TrainResult:
    """Train (or resume) a racing policy.

    Args:
        timesteps: total environment steps (counting those of a resumed run).
        progress: ``f(timesteps, curriculum)`` called every step.
        max_wall_s: stop (and save) once training has used this much wall-clock time in total.
        callbacks: ``f(curriculum, elapsed)`` returning more stable-baselines3 callbacks, run after
            the built-in ones (``elapsed()``: training wall time so far, s; the sweep reports its
            objective this way).
    """
    import torch
    from stable_baselines3 import PPO
    from stable_baselines3.common.callbacks import BaseCallback, CallbackList

    out = Path(out)
    ckpt_dir = out / "checkpoints"
    total = timesteps if timesteps is not None else cfg.total_timesteps
    quad = train_quad(cfg)  # a bad quadrotor file fails before anything is written
    state = {"stage": 0, "best": [-1, -1.0], "wall_s": 0.0, "metrics": []}
    if resume:
        last = ckpt_dir / "last.zip"
        if not last.is_file():
            raise FileNotFoundError(f"{last}: no checkpoint to resume from")
        state_path = ckpt_dir / "last_state.json"
        try:
            state = json.loads(state_path.read_text())
        except (OSError, json.JSONDecodeError) as e:
            raise ValueError(f"{state_path}: corrupt checkpoint state ({e})") from None
        if (
            not isinstance(state, dict)
            or not isinstance(state.get("stage"), int)
            or not (isinstance(state.get("best"), list) and len(state["best"]) == 2)
        ):
            raise ValueError(f"{state_path}: corrupt checkpoint state (no stage or best entry)")
        if (out / "config.json").is_file():
            differ = config_differences(load_run_config(out), cfg)
            if differ:
                raise ValueError(
                    f"{out} was trained with another config (differs in {', '.join(differ)}); "
                    "resume it with its own config (leave out --config and the other settings) "
                    "or choose another --out"
                )
    elif ckpt_dir.exists() and any(ckpt_dir.iterdir()):
        raise ValueError(
            f"{out}: holds a previous run; pass --resume to continue it or choose another --out"
        )
    out.mkdir(parents=True, exist_ok=True)
    atomic_write_json(out / "config.json", config_to_dict(cfg))
    torch.set_num_threads(cfg.ppo.torch_threads)

    p = cfg.ppo
    stages = curriculum_of(cfg)
    stage = int(state["stage"])
    if not 0 <= stage < len(stages.stages):
        raise ValueError(
            f"{ckpt_dir / 'last_state.json'}: curriculum stage {stage} is out of range for this config"
        )
    features = run_features(cfg)
    env = make_train_env(
        cfg, p.num_envs, stages.stages[stage], seed, stages.difficulty_at(stage), features,
        stages.layout_replay, quad, stages.crash_replay, stages.plan_start,
    )  # fmt: skip
    reference = _feature_env(env).reference  # the plan the policy reads, exported with it
    if resume:
        try:
            model = PPO.load(ckpt_dir / "last.zip", env=env, device="cpu")
        except Exception as e:  # noqa: BLE001 - a broken zip is a user-facing error
            raise ValueError(
                f"{ckpt_dir / 'last.zip'}: corrupt checkpoint ({type(e).__name__}: {e})"
            ) from None
    else:
        policy_kwargs = {"net_arch": list(p.net_arch), "log_std_init": p.log_std_init}
        policy_class = "MlpPolicy"
        if cfg.privileged_critic:
            policy_class = AsymmetricActorCriticPolicy
            policy_kwargs["actor_dim"] = env.actor_dim
        model = PPO(
            policy_class,
            env,
            learning_rate=p.learning_rate,
            n_steps=p.n_steps,
            batch_size=p.batch_size,
            n_epochs=p.n_epochs,
            gamma=p.gamma,
            gae_lambda=p.gae_lambda,
            clip_range=p.clip_range,
            ent_coef=p.ent_coef,
            vf_coef=p.vf_coef,
            max_grad_norm=p.max_grad_norm,
            normalize_advantage=p.advantage_norm == "minibatch",
            policy_kwargs=policy_kwargs,
            tensorboard_log=str(out / "tb"),
            seed=seed,
            device="cpu",
            verbose=0,
        )
        with torch.no_grad():  # start from hover: mean thrust action balances gravity
            model.policy.action_net.bias[0] = quad.hover_thrust_action
        if cfg.init is not None:
            load_init_actor(model, cfg.init, cfg.observation, features, cfg.reference is not None)

    curriculum = CurriculumCallback(stages, stage=stage, verbose=verbose)
    metrics = MetricsCallback(curriculum, progress=progress)
    metrics.rows = list(state.get("metrics", []))
    metrics.wall_offset = float(state.get("wall_s", 0.0))
    best = list(state["best"])

    def fraction() -> float:  # how much of the run is done, for the schedules
        f = model.num_timesteps / max(total, 1)
        return f if max_wall_s is None else max(f, metrics.elapsed() / max_wall_s)

    anneal = None
    if p.learning_rate_final is not None or p.log_std_final is not None:
        anneal = Anneal(fraction, p.learning_rate, p.learning_rate_final, p.log_std_final,
                        state.get("log_std_start"))  # fmt: skip

    def snapshot() -> dict:
        return {"stage": curriculum.stage, "best": best, "wall_s": metrics.elapsed(), "metrics": metrics.rows,
                "timesteps": int(model.num_timesteps),
                **({} if anneal is None or anneal.std_start is None else {"log_std_start": anneal.std_start})}  # fmt: skip

    class Periodic(BaseCallback):
        def __init__(self) -> None:
            super().__init__()
            self.next_ckpt = model.num_timesteps + cfg.checkpoint_every
            self.next_eval = model.num_timesteps + cfg.eval_every

        def _on_step(self) -> bool:
            if max_wall_s is not None and metrics.elapsed() >= max_wall_s:
                return False
            if self.num_timesteps >= self.next_eval:
                self.next_eval += cfg.eval_every
                n = curriculum.num_gates
                eval_seed = seed + 10_000 + (0 if cfg.eval_same_layouts else self.num_timesteps)
                ev = evaluate_model(
                    model,
                    cfg,
                    n,
                    cfg.eval_episodes,
                    eval_seed,
                    curriculum.difficulty,
                    features,
                    quad,
                )
                self.logger.record("eval/success_rate", ev.success)
                self.logger.record("eval/score", ev.score)
                if ev.lap_per_gate_s is not None:
                    self.logger.record("eval/lap_per_gate_s", ev.lap_per_gate_s)
                meta = {
                    "name": f"evaluated-{self.num_timesteps}",
                    "timesteps": int(self.num_timesteps),
                    "num_gates": n,
                    "difficulty": curriculum.difficulty,
                    "eval_success": ev.success,
                    "eval_lap_per_gate_s": ev.lap_per_gate_s,
                    "quad": quad.name,
                }
                evaluated = out / "evaluated" / f"{self.num_timesteps:09d}"
                evaluated.parent.mkdir(exist_ok=True)
                export_sb3_policy(model, evaluated, cfg.observation, meta, features, reference)
                if (curriculum.stage, ev.score) > tuple(best):
                    best[:] = [curriculum.stage, ev.score]
                    meta = {**meta, "name": "best"}
                    export_sb3_policy(
                        model, out / "best", cfg.observation, meta, features, reference
                    )
            if self.num_timesteps >= self.next_ckpt:
                self.next_ckpt += cfg.checkpoint_every
                _save_checkpoint(model, ckpt_dir, snapshot())
            return True

    extra = [] if callbacks is None else list(callbacks(curriculum, metrics.elapsed))
    callbacks = [curriculum, metrics, Periodic()]
    if cfg.init is not None and cfg.init_critic_steps > 0:
        callbacks.append(CriticWarmup(cfg.init_critic_steps))
    if p.advantage_norm == "running":
        callbacks.append(RunningAdvantageNorm())
    if anneal is not None:
        callbacks.append(anneal)
    callbacks += extra
    remaining = max(total - int(model.num_timesteps), 0) if resume else total
    try:
        if remaining > 0:
            model.learn(
                remaining,
                callback=CallbackList(callbacks),
                reset_num_timesteps=not resume,
                tb_log_name="ppo",
            )
    except KeyboardInterrupt:
        _save_checkpoint(model, ckpt_dir, snapshot())
        atomic_write_json(out / "metrics.json", metrics.rows)
        raise
    _save_checkpoint(model, ckpt_dir, snapshot())
    atomic_write_json(out / "metrics.json", metrics.rows)
    meta = {"name": out.name, "timesteps": int(model.num_timesteps), "num_gates": curriculum.num_gates,
            "seed": seed, "preset": cfg.preset, "quad": quad.name}  # fmt: skip
    policy_path = export_sb3_policy(
        model, out / "policy", cfg.observation, meta, features, reference
    )
    if not (out / "best.safetensors").exists():
        for ext in (".safetensors", ".json"):
            shutil.copyfile(out / f"policy{ext}", out / f"best{ext}")
    return TrainResult(
        out, int(model.num_timesteps), curriculum.stage, curriculum.num_gates, best[1], policy_path
    )
