"""Training configuration: frozen dataclasses loaded from TOML, with the `classic` and `fast` presets."""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field, fields, is_dataclass, replace
from pathlib import Path

from icarus_vision.fileio import read_toml
from icarus_vision.policy.features import FEATURES_VERSIONS
from icarus_vision.sim.config import (
    PROGRESS_REWARD,
    RACING_LINE_REWARD,
    RandomizationConfig,
    RewardConfig,
)
from icarus_vision.sim.observation import OBS_DIMS
from icarus_vision.validation import check_table, require_table

REWARD_PRESETS = ("progress", "racing", "racing-line", "plan-line")


@dataclass(frozen=True)
class PPOConfig:
    """stable-baselines3 PPO hyperparameters (rollout size = num_envs × n_steps)."""

    num_envs: int = 256
    """Drones simulated together in one BatchedRacingVecEnv."""
    n_steps: int = 64
    """Steps per drone per rollout."""
    batch_size: int = 4096
    """Minibatch size."""
    n_epochs: int = 7
    """Passes over each rollout."""
    learning_rate: float = 1e-3
    """Adam learning rate (at the start of the run)."""
    learning_rate_final: float | None = None
    """Learning rate at the end of the run, reached linearly (None: constant). The run's end is
    its timesteps, or its ``--max-minutes`` where that comes first."""
    gamma: float = 0.99
    """Discount factor."""
    gae_lambda: float = 0.95
    """GAE λ."""
    clip_range: float = 0.2
    """PPO clipping."""
    ent_coef: float = 0.0
    """Entropy bonus."""
    vf_coef: float = 0.5
    """Value-loss weight."""
    max_grad_norm: float = 0.5
    """Gradient clipping."""
    net_arch: tuple[int, ...] = (64, 64)
    """Hidden layers of the policy and value MLPs (separate networks)."""
    log_std_init: float = 0.0
    """Initial log standard deviation of the Gaussian policy."""
    log_std_final: float | None = None
    """Ceiling on the policy's log standard deviation, lowered linearly from where each action
    axis starts to this by the run's end (as ``learning_rate_final``): exploration narrows as
    the run ends (None: the log std is learned freely)."""
    advantage_norm: str = "minibatch"
    """"minibatch" (SB3's per-minibatch normalisation) or "running" (Welford statistics over all
    rollouts so far, applied to whole rollouts)."""
    torch_threads: int = 2
    """Torch intra-op threads (the update and the rollout alternate, so both cores serve the update)."""


@dataclass(frozen=True)
class CurriculumConfig:
    """Gate-count curriculum on random tracks."""

    stages: tuple[int, ...] = (1, 3, 5, 10)
    """Gates per episode at each stage."""
    difficulty: tuple[float, ...] | None = None
    """Race-layout difficulty at each stage (same length as ``stages``; see ``race_track``), so
    the curriculum widens the layouts as well as lengthening them; None: the classic
    ``random_track`` layouts at every stage."""

    def difficulty_at(self, stage: int) -> float | None:
        """Race-layout difficulty at ``stage`` (None: classic layouts)."""
        return None if self.difficulty is None else float(self.difficulty[stage])

    promote_success: float = 0.8
    """Success rate (all gates, no crash) over the window needed to promote."""
    window: int = 100
    """Episodes in the success window."""
    min_episodes: int = 20
    """Episodes at a stage before a promotion is considered."""
    layout_replay: float = 0.0
    """Random tracks: the chance that a training episode re-flies a layout the policy failed on
    (prioritised level replay; ``EnvConfig.layout_replay``). Replayed episodes do not count
    towards promotion, and evaluations always draw new layouts. 0: every layout new."""
    crash_replay: float = 0.0
    """The chance that a training episode starts again from a state flown 0.4–1.6 s before an
    earlier crash of the batch, on that episode's track with its parameters and wind
    (``EnvConfig.crash_replay``): more of the moments the policy fails at. Such episodes do not
    count towards promotion. 0: every episode from the start."""
    plan_start: float = 0.0
    """Specialists (a fixed ``track``): the chance that a training episode starts from a state of
    the track's time-optimal plan, drawn uniformly along it between the passages, with the
    plan's speed, attitude and rates (``EnvConfig.plan_start``; the plan is solved and cached
    when missing), so the policy meets the plan's line without having to find it first. Such
    episodes do not count towards promotion. 0: every episode from the start."""


@dataclass(frozen=True)
class PerceptionNoiseConfig:
    """Noise on obs[12:15] standing in for the vision pipeline during training."""

    enabled: bool = True
    """Apply perception noise."""
    error_model: str | None = None
    """Detector error model JSON (from eval-detector); None: the parametric default below."""
    sigma_base_m: float = 0.02
    """Position noise standard deviation at zero distance, m."""
    sigma_per_m: float = 0.015
    """Growth of the standard deviation per metre of distance."""
    miss_base: float = 0.05
    """Probability of a missed detection at zero distance (the last estimate is held)."""
    miss_per_m: float = 0.01
    """Growth of the miss probability per metre."""
    out_of_view: bool = False
    """A gate outside the camera's field of view is never seen (its last estimate is held)."""
    map_error_m: float = 0.0
    """Error of the map a new target gate starts from: its first estimate is the truth moved
    uniformly within ± this per axis, as a race's estimator starts from the nominal layout while
    randomisation moves each gate within ± ``gate_pos_jitter_m`` (0.3); until the gate is seen
    the policy flies on that. 0: the first estimate is an ordinary detection (σ at its distance)."""
    map_yaw_error_deg: float = 0.0
    """With the extended observation: a new target gate's passage direction is turned uniformly
    within ± this until the gate is seen (the map's heading; randomisation turns gates up to
    ±10°), and the gate after it is off by ± ``map_error_m`` per axis, as a race reads both from
    the map. 0: both true."""
    map_share: float = 1.0
    """The share of the training drones that fly with the map's errors above (the others start
    each gate from an ordinary detection), so a policy learns the map's errors without giving up
    the flight on known gates. 1: all of them."""
    bias_m: float = 0.0
    """A persistent error per gate, as an estimator's near errors are (a gate's reads err the
    same way frame after frame, and the filter follows them): each target gate's detections are
    all off by one draw of N(0, this²) per axis, on top of the white noise above. 0: none."""
    bias_share: float = 1.0
    """The share of the training drones (the first of the batch: with ``map_share`` equal, the
    same drones) that fly with ``bias_m``, so the others keep the flight on well-known gates.
    1: all of them."""


@dataclass(frozen=True)
class TrainConfig:
    """Everything `train-policy` needs."""

    preset: str = "fast"
    """Name of the preset this config started from."""
    total_timesteps: int = 20_000_000
    """Environment steps to train for."""
    ppo: PPOConfig = field(default_factory=PPOConfig)
    """PPO hyperparameters."""
    curriculum: CurriculumConfig = field(default_factory=CurriculumConfig)
    """Gate-count curriculum."""
    randomization: RandomizationConfig = field(
        default_factory=lambda: RandomizationConfig(enabled=True)
    )
    """Domain randomisation (on by default for training)."""
    perception: PerceptionNoiseConfig = field(default_factory=PerceptionNoiseConfig)
    """Perception noise on the gate observation."""
    reward: str = "progress"
    """"progress" (the simulation core's reward), "racing" (adds speed toward the gate and a
    time penalty), "racing-line" (progress along the segment between gates, small smoothness
    and perception costs; ``sim.config.RACING_LINE_REWARD``) or "plan-line" (racing-line with the
    progress measured along the fixed ``track``'s time-optimal plan instead of the straight
    segments, so a line wider than the plan's pays later; the plan is solved and cached under
    ``runs/plans`` when missing)."""
    time_cost: float = 0.0
    """Cost per second of flight added to the reward preset's (≥ 0; e.g. 2.0 makes every second
    cost as much as 2 m of progress), so a policy values lap time beyond the discount."""
    perception_cost: float | None = None
    """Cost per radian, every step, that the next gate lies outside the free cone around the
    camera's axis (≥ 0; None: the reward preset's, 0.05 for racing-line), so the policy keeps
    the gate in view at the price of some speed."""
    crash_cost: float | None = None
    """Cost of a crash (≥ 0; None: the reward preset's, 10). With a discount of 0.99 at 50 Hz
    the future a crash forfeits counts for about two seconds, so this weight sets how much margin
    the policy keeps from frames and ground."""
    center_reward: float | None = None
    """Reward per gate passed through its centre, falling linearly to 0 at the opening's edge
    (≥ 0; None: the preset's, 0)."""
    align_reward: float | None = None
    """Reward per gate passed straight through, times the cosine between the crossing and the
    passage direction (0.5 of it at 60° off the normal; ≥ 0; None: the preset's, 0). Oblique
    crossings are where gate collisions happen: an opening's window narrows with the angle."""
    observation: str = "basic"
    """"basic" (15-D), "extended" (21-D: adds the next gate's direction and the gate after) or
    "racing" (25-D: adds the next gate's opening side and the gate after's direction)."""
    features: str | None = None
    """The policy's input transform (``policy/features.py``): "v1", or "v2" (adds the drone's place
    and velocity in the next gate's frame and its straight-on crossing point; extended and racing
    observations); None: the ``init`` policy's (so ``--init default`` continues the shipped
    generalist as it reads), v1 without one."""
    reference: str | None = None
    """"plan": the policy also reads its track's time-optimal plan where the drone is (the nearest
    node's offset, velocity, the velocity 0.3 s on, thrust axis and thrust: ``policy/reference.py``;
    a fixed track and the extended or racing observation; the plan is solved and cached when
    missing, and travels in the exported policy); None: it does not."""
    max_episode_s: float | None = None
    """Episode time limit; None: the environment default (5 s + 3 s per gate)."""
    track: str | None = None
    """Fixed track (built-in name or TOML path) for a specialist; None: random tracks with the
    curriculum. With a track the curriculum has one stage: the whole track."""
    quad: str | None = None
    """Quadrotor TOML file the policy is trained for (its dynamics, limits and camera: the
    camera-angle cost and the out-of-view rule use its camera; randomisation varies mass, thrust
    and drag around it); None: the built-in racer-500g. Race it with ``race --quad`` the same file."""
    privileged_critic: bool = False
    """The value network also reads the truth the policy is not given (the gate without perception
    noise, the randomised mass, thrust, drag and motor lag, the wind, the next opening's size, the
    gates left: ``policy/critic.py``); the actor, the only part exported, reads as before."""
    init: str | None = None
    """Start the actor from an exported policy (``default`` or a path); None: from scratch."""
    init_critic_steps: int = 0
    """With ``init``: environment steps during which only the value network learns, so the first
    policy updates do not follow a random critic."""
    checkpoint_every: int = 1_000_000
    """Environment steps between checkpoints."""
    eval_every: int = 1_000_000
    """Environment steps between evaluations for the best model."""
    eval_episodes: int = 64
    """Episodes per evaluation (random tracks at the current curriculum stage)."""
    eval_same_layouts: bool = False
    """Every evaluation flies the same layouts (seed + 10,000), so the best model is chosen by the
    policy and not by the draw; False: each evaluation draws its own (seed + 10,000 + steps), as
    every run before 2026-12-05 did (its evaluations of one policy swung by 10 points)."""

    def __post_init__(self) -> None:
        validate_train_config(self)

    def reward_config(self) -> RewardConfig:
        if self.reward == "progress":
            base = PROGRESS_REWARD
        elif self.reward == "racing-line":
            base = RACING_LINE_REWARD
        elif self.reward == "plan-line":
            base = replace(RACING_LINE_REWARD, line=0.0, path=1.0)
        else:
            base = RewardConfig(speed=0.5, time=-1.0)
        if self.time_cost:
            base = replace(base, time=base.time - self.time_cost)
        if self.perception_cost is not None:
            base = replace(base, perception=-self.perception_cost)
        if self.crash_cost is not None:
            base = replace(base, crash=-self.crash_cost)
        if self.center_reward is not None:
            base = replace(base, center=self.center_reward)
        if self.align_reward is not None:
            base = replace(base, align=self.align_reward)
        return base


def validate_train_config(c: TrainConfig) -> None:
    """Raise ValueError naming the first out-of-range value."""
    p = c.ppo
    checks = [
        ("total_timesteps", c.total_timesteps >= 1),
        ("ppo.num_envs", p.num_envs >= 1),
        ("ppo.n_steps", p.n_steps >= 1),
        ("ppo.batch_size", 1 <= p.batch_size <= p.num_envs * p.n_steps),
        ("ppo.n_epochs", p.n_epochs >= 1),
        ("ppo.learning_rate", 0 < p.learning_rate < 1),
        (
            "ppo.learning_rate_final",
            p.learning_rate_final is None or 0 <= p.learning_rate_final < 1,
        ),
        ("ppo.log_std_final", p.log_std_final is None or -10 <= p.log_std_final <= 2),
        ("ppo.gamma", 0 < p.gamma <= 1),
        ("ppo.gae_lambda", 0 <= p.gae_lambda <= 1),
        ("ppo.clip_range", 0 < p.clip_range < 1),
        ("ppo.ent_coef", p.ent_coef >= 0),
        ("ppo.net_arch", len(p.net_arch) >= 1 and all(n >= 1 for n in p.net_arch)),
        ("ppo.advantage_norm", p.advantage_norm in ("minibatch", "running")),
        ("ppo.torch_threads", p.torch_threads >= 1),
        (
            "curriculum.stages",
            len(c.curriculum.stages) >= 1 and all(n >= 1 for n in c.curriculum.stages),
        ),
        ("curriculum.promote_success", 0 < c.curriculum.promote_success <= 1),
        ("curriculum.window", c.curriculum.window >= 1),
        ("curriculum.min_episodes", 1 <= c.curriculum.min_episodes),
        ("curriculum.layout_replay", 0 <= c.curriculum.layout_replay < 1),
        ("curriculum.crash_replay", 0 <= c.curriculum.crash_replay < 1),
        ("curriculum.plan_start", 0 <= c.curriculum.plan_start < 1),
        (
            "curriculum.difficulty",
            c.curriculum.difficulty is None
            or (
                len(c.curriculum.difficulty) == len(c.curriculum.stages)
                and all(0 <= d <= 1 for d in c.curriculum.difficulty)
            ),
        ),
        ("reward", c.reward in REWARD_PRESETS),
        ("observation", c.observation in OBS_DIMS),
        ("features", c.features is None or c.features in FEATURES_VERSIONS),
        ("reference", c.reference in (None, "plan")),
        ("checkpoint_every", c.checkpoint_every >= 1),
        ("eval_every", c.eval_every >= 1),
        ("eval_episodes", c.eval_episodes >= 1),
        ("init_critic_steps", c.init_critic_steps >= 0),
        ("time_cost", c.time_cost >= 0),
        ("perception_cost", c.perception_cost is None or c.perception_cost >= 0),
        ("crash_cost", c.crash_cost is None or c.crash_cost >= 0),
        ("center_reward", c.center_reward is None or c.center_reward >= 0),
        ("align_reward", c.align_reward is None or c.align_reward >= 0),
        ("randomization.mass_pct", 0 <= c.randomization.mass_pct < 1),
        ("randomization.thrust_pct", 0 <= c.randomization.thrust_pct < 1),
        ("randomization.motor_tau_pct", 0 <= c.randomization.motor_tau_pct < 1),
        ("randomization.drag_pct", 0 <= c.randomization.drag_pct < 1),
        ("randomization.wind_mps", c.randomization.wind_mps >= 0),
        ("randomization.gust_mps", c.randomization.gust_mps >= 0),
        ("randomization.gate_pos_jitter_m", c.randomization.gate_pos_jitter_m >= 0),
        ("randomization.gate_yaw_jitter_deg", 0 <= c.randomization.gate_yaw_jitter_deg <= 180),
        ("randomization.start_pos_jitter_m", c.randomization.start_pos_jitter_m >= 0),
        ("perception.sigma_base_m", c.perception.sigma_base_m >= 0),
        ("perception.sigma_per_m", c.perception.sigma_per_m >= 0),
        ("perception.miss_base", 0 <= c.perception.miss_base <= 1),
        ("perception.miss_per_m", c.perception.miss_per_m >= 0),
        ("perception.map_error_m", c.perception.map_error_m >= 0),
        ("perception.map_yaw_error_deg", 0 <= c.perception.map_yaw_error_deg <= 180),
        ("perception.map_share", 0 <= c.perception.map_share <= 1),
        ("perception.bias_m", 0 <= c.perception.bias_m < 1),
        ("perception.bias_share", 0 <= c.perception.bias_share <= 1),
        ("max_episode_s", c.max_episode_s is None or c.max_episode_s > 0),
    ]
    for name, ok in checks:
        if not ok:
            raise ValueError(f"train config: {name} is out of range ({_get(c, name)!r})")
    if c.reward == "plan-line" and c.track is None:
        raise ValueError("train config: reward 'plan-line' needs a fixed track (set track)")
    if c.curriculum.plan_start > 0 and c.track is None:
        raise ValueError("train config: curriculum.plan_start needs a fixed track (set track)")
    if c.reference is not None and (c.track is None or c.observation == "basic"):
        raise ValueError(
            "train config: reference 'plan' needs a fixed track (set track) and the extended or "
            "racing observation"
        )
    for sub in (c.ppo, c.randomization, c.perception):
        for f in fields(sub):
            v = getattr(sub, f.name)
            if isinstance(v, float) and not math.isfinite(v):
                raise ValueError(f"train config: {f.name} must be finite, got {v}")


def _get(obj, dotted: str):
    for part in dotted.split("."):
        obj = getattr(obj, part)
    return obj


CLASSIC = TrainConfig(
    preset="classic",
    ppo=PPOConfig(
        num_envs=8,
        n_steps=256,  # 8 × 256 = the classic 2048-step rollout
        batch_size=64,
        n_epochs=10,
        learning_rate=3e-4,
        gamma=0.99,
        gae_lambda=0.95,
        clip_range=0.2,
        ent_coef=0.01,
        net_arch=(64, 64),
    ),
)
FAST = TrainConfig(preset="fast")
RACING = TrainConfig(
    preset="racing",
    total_timesteps=200_000_000,
    ppo=replace(FAST.ppo, learning_rate=5e-4, log_std_init=-1.0),
    curriculum=CurriculumConfig(
        stages=(5, 10, 10, 10, 10), difficulty=(0.25, 0.25, 0.5, 0.75, 1.0)
    ),
    perception=PerceptionNoiseConfig(out_of_view=True),
    reward="racing-line",
    observation="extended",
    init="classic",
    init_critic_steps=2_000_000,
    checkpoint_every=5_000_000,
    eval_every=5_000_000,
    eval_episodes=128,
)
"""The racing generalist: fine-tunes the classic generalist with the racing-line reward on race
layouts whose difficulty grows with the curriculum; gates outside the camera's view are not seen."""
SPECIALIST = replace(
    RACING,
    preset="specialist",
    total_timesteps=25_000_000,
    ppo=replace(RACING.ppo, learning_rate=3e-4, log_std_init=-1.5),
    time_cost=2.0,
    init="default",
    init_critic_steps=1_000_000,
    checkpoint_every=2_500_000,
    eval_every=2_500_000,
    eval_episodes=64,
)
"""A specialist: the shipped generalist fine-tuned on one track (set ``track``), randomisation on,
with a time cost of 2 per second so it trades safety margin for lap time on the track it knows."""
PRESETS = {"classic": CLASSIC, "fast": FAST, "racing": RACING, "specialist": SPECIALIST}


def config_from_dict(data: dict, source: str = "<memory>") -> TrainConfig:
    """A TrainConfig from a parsed TOML table: ``preset`` picks the base, other keys override it."""
    require_table(data, source)
    nested = {k: v for k, v in data.items() if is_dataclass(getattr(FAST, k, None))}
    data = {
        **check_table(TrainConfig, {k: v for k, v in data.items() if k not in nested}, source),
        **nested,
    }
    preset = data.pop("preset", "fast")
    if preset not in PRESETS:
        raise ValueError(f"{source}: unknown preset {preset!r}; choose one of {sorted(PRESETS)}")
    base = PRESETS[preset]
    kwargs = {}
    for key, value in data.items():
        current = getattr(base, key)
        if is_dataclass(current):
            kwargs[key] = replace(current, **check_table(type(current), value, f"{source} [{key}]"))
        else:
            kwargs[key] = value
    try:
        return replace(base, **kwargs)
    except (TypeError, ValueError) as e:
        raise ValueError(f"{source}: {e}") from None


def load_train_config(path: str | Path) -> TrainConfig:
    """Load a training config TOML; errors name the file and the key."""
    data = read_toml(path, "config", FileNotFoundError)
    return config_from_dict(data, str(path))


def config_to_dict(c: TrainConfig) -> dict:
    """JSON-friendly dict of a config (tuples become lists)."""
    return asdict(c)


def config_differences(a: TrainConfig, b: TrainConfig) -> list[str]:
    """Dotted names of the settings in which two configs differ."""
    da, db = config_to_dict(a), config_to_dict(b)
    out = []
    for key in da:
        if isinstance(da[key], dict):
            out += [f"{key}.{k}" for k in da[key] if da[key][k] != db[key].get(k)]
        elif da[key] != db[key]:
            out.append(key)
    return out


def load_run_config(out: str | Path) -> TrainConfig:
    """The config a run was started with (``OUT/config.json``); errors name the file."""
    import json

    path = Path(out) / "config.json"
    if not path.is_file():
        raise FileNotFoundError(f"{path}: the run's config is missing; cannot resume it")
    try:
        data = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as e:
        raise ValueError(f"{path}: unreadable run config ({e})") from None
    if not isinstance(data, dict):
        raise ValueError(f"{path}: the run config must be a JSON object")
    return config_from_dict(data, str(path))
