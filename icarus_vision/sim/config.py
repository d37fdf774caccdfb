"""Configuration dataclasses of the racing environment (frozen; TOML or code builds them)."""

from __future__ import annotations

from dataclasses import dataclass, field

from icarus_vision.sim.observation import OBS_DIMS
from icarus_vision.sim.quad import QuadParams
from icarus_vision.sim.track import Track


@dataclass(frozen=True)
class RewardConfig:
    """Weights of the named reward terms (see ``sim/reward.py``)."""

    progress: float = 1.0
    """Per metre of distance gained toward the next gate (previous − current distance)."""
    gate: float = 100.0
    """Per gate passed."""
    crash: float = -10.0
    """Once, on a crash."""
    attitude: float = -0.01
    """Per radian of |roll| + |pitch|, every step."""
    speed: float = 0.0
    """Per m/s of velocity toward the next gate, every step (0 in the progress preset)."""
    time: float = 0.0
    """Per second of flight (a negative value is a time penalty; 0 in the progress preset)."""
    line: float = 0.0
    """Per metre flown along the racing line: the segment from the previous gate (or the start) to
    the next gate (Song et al. 2021); where that segment is shorter than 1 m (a gate flown straight
    back), toward the gate instead."""
    path: float = 0.0
    """Per metre flown along a reference path, such as a fixed track's time-optimal plan: from the
    previous passage (or the start) to the next, the position's nearest point on it
    (``RaceCore.set_reference``; the ``plan-line`` preset), so a wider line than the plan's earns
    its metres later."""
    perception: float = 0.0
    """Per radian, every step, that the next gate lies outside a cone of ``perception_cone_deg``
    around the camera's optical axis (a negative value keeps the gate in view)."""
    perception_cone_deg: float = 30.0
    """Half-angle of the cone around the optical axis that costs nothing, degrees."""
    rates: float = 0.0
    """Per rad/s of body-rate magnitude, every step (a negative value is a smoothness cost)."""
    action_change: float = 0.0
    """Per unit of squared change of the action since the previous step."""
    center: float = 0.0
    """Per gate passed, times how central the passage was: 1 through the centre, 0 at the
    opening's edge (1 − max(|y|, |z|) / half the opening), so margin from the frame pays."""
    align: float = 0.0
    """Per gate passed, times the cosine between the crossing step and the passage direction: 1
    straight through, 0.5 at 60° off the gate's normal (``rules.crossing_alignment``), so setting
    up for a gate before it pays (an oblique crossing leaves a narrower window)."""


PROGRESS_REWARD = RewardConfig()
"""The ``progress`` preset: distance gained toward the next gate, a large gate bonus."""
RACING_LINE_REWARD = RewardConfig(
    progress=0.0,
    gate=5.0,
    crash=-10.0,
    attitude=0.0,
    line=1.0,
    perception=-0.05,
    rates=-5e-4,
    action_change=-2e-3,
)
"""The ``racing-line`` preset: progress along the racing line values time; small smoothness and
perception costs; no term pays for staying anywhere."""


@dataclass(frozen=True)
class RandomizationConfig:
    """Domain randomisation applied at every reset when ``enabled`` (off by default)."""

    enabled: bool = False
    """Master switch."""
    mass_pct: float = 0.2
    """Mass scale drawn uniformly in [1 − p, 1 + p]."""
    thrust_pct: float = 0.1
    """Maximum-thrust scale drawn uniformly in [1 − p, 1 + p]."""
    wind_mps: float = 2.0
    """Constant wind: horizontal air velocity of uniform random direction, speed in [0, wind_mps]."""
    gust_mps: float = 1.0
    """Gust amplitude per axis (sum of three random sinusoids, 0.1–1 Hz), m/s."""
    gate_pos_jitter_m: float = 0.3
    """Each gate centre moved uniformly within ± this per axis (z kept ≥ 0.8 m)."""
    gate_yaw_jitter_deg: float = 10.0
    """Each gate heading turned uniformly within ± this."""
    start_pos_jitter_m: float = 0.0
    """Start position moved horizontally within ± this."""
    motor_tau_pct: float = 0.0
    """Thrust and rate-loop time constant scaled by a draw in [1 − p, 1 + p] (a different rate
    controller or motors; 0: the file's)."""
    drag_pct: float = 0.0
    """Each body axis's drag coefficient scaled by its own draw in [1 − p, 1 + p] (0: the file's)."""


@dataclass(frozen=True)
class EnvConfig:
    """Everything a DroneRacingEnv needs; the same config drives both backends."""

    track: Track | None = None
    """Fixed track (None: the default built-in track). Ignored when ``random_tracks``."""
    random_tracks: bool = False
    """Draw a new procedural track (``random_track``) for every episode."""
    num_gates: int | None = None
    """Gates per episode: the first n of a fixed track, or n random gates (None: all / 10)."""
    layout_difficulty: float | None = None
    """Random tracks only: None draws the classic ``random_track`` layouts; a value in [0, 1]
    draws ``race_track`` layouts of that difficulty (1: the full ranges and motifs)."""
    layout_replay: float = 0.0
    """Random tracks only: the chance that an episode re-flies a layout some drone of the batch
    failed on (crash or time-out) instead of drawing a new one (the gates jittered afresh); each
    failed layout is flown again once, and again after each further failure. 0: every layout new."""
    crash_replay: float = 0.0
    """The chance that an episode starts again from a state a drone of the batch flew shortly
    before it crashed (on that drone's track, with its parameters, wind and clock) instead of
    from the start (the state replay of hard moments; training on the batched backend). Each
    crash is replayed once. 0: every episode from the start."""
    plan_start: float = 0.0
    """Fixed tracks: the chance that an episode starts from a state of the track's time-optimal
    plan (position, velocity, attitude, body rates and thrust at a node drawn uniformly between
    the passages, the next passage its target, the clock at the node's time) instead of from the
    start, so the policy meets the plan's line at the plan's speed (``RaceCore.set_plan``;
    training on the batched backend). 0: every episode from the start."""
    crash_replay_s: tuple[float, float] = (0.4, 1.6)
    """How long before the crash the replayed state was flown, s: drawn uniformly in this range
    (to the nearest snapshot; snapshots every 0.2 s, kept for 2 s)."""
    quad: QuadParams = field(default_factory=QuadParams)
    """The quadrotor."""
    ctrl_hz: float = 50.0
    """Control (action) rate, Hz."""
    physics_hz: float = 200.0
    """Physics rate, Hz; must be an integer multiple of ``ctrl_hz``."""
    max_episode_s: float | None = None
    """Time limit (truncation); None: 5 s + 3 s per gate passage."""
    gate_obs_frame: str = "world"
    """Frame of obs[12:15], the next gate's relative position: "world" or "body"."""
    observation: str = "basic"
    """"basic": the 15-D observation. "extended": 21-D, the 15-D vector plus the next gate's
    passage direction (unit vector, 15:18) and the relative position of the gate after it (18:21),
    both in the frame of ``gate_obs_frame``. "racing": 25-D, the extended vector plus the next
    gate's opening side in metres (21) and the passage direction of the gate after it (22:25)."""
    reward: RewardConfig = field(default_factory=RewardConfig)
    """Reward weights."""
    randomization: RandomizationConfig = field(default_factory=RandomizationConfig)
    """Domain randomisation."""

    def __post_init__(self) -> None:
        ratio = self.physics_hz / self.ctrl_hz
        if self.ctrl_hz <= 0 or abs(ratio - round(ratio)) > 1e-9 or round(ratio) < 1:
            raise ValueError(
                f"physics_hz ({self.physics_hz}) must be a positive integer multiple of ctrl_hz ({self.ctrl_hz})"
            )
        if self.gate_obs_frame not in ("world", "body"):
            raise ValueError(
                f"gate_obs_frame must be 'world' or 'body', got {self.gate_obs_frame!r}"
            )
        if self.observation not in OBS_DIMS:
            raise ValueError(
                f"observation must be one of {', '.join(OBS_DIMS)}, got {self.observation!r}"
            )
        if self.layout_difficulty is not None and not 0.0 <= self.layout_difficulty <= 1.0:
            raise ValueError(
                f"layout_difficulty must be in [0, 1] or None, got {self.layout_difficulty}"
            )
        if not 0.0 <= self.layout_replay < 1.0:
            raise ValueError(f"layout_replay must be in [0, 1), got {self.layout_replay}")
        if not 0.0 <= self.crash_replay < 1.0:
            raise ValueError(f"crash_replay must be in [0, 1), got {self.crash_replay}")
        if not 0.0 <= self.plan_start < 1.0:
            raise ValueError(f"plan_start must be in [0, 1), got {self.plan_start}")
        lo, hi = self.crash_replay_s
        if not 0.0 < lo <= hi <= 2.0:
            raise ValueError(
                f"crash_replay_s must be (lo, hi) with 0 < lo <= hi <= 2 s, got {self.crash_replay_s}"
            )
        if self.num_gates is not None and self.num_gates < 1:
            raise ValueError(f"num_gates must be >= 1, got {self.num_gates}")

    @property
    def obs_dim(self) -> int:
        return OBS_DIMS[self.observation]

    @property
    def substeps(self) -> int:
        return int(round(self.physics_hz / self.ctrl_hz))

    @property
    def dt(self) -> float:
        """Control period, s."""
        return 1.0 / self.ctrl_hz
