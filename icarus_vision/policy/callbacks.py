"""stable-baselines3 callbacks: gate-count curriculum, running advantage normalisation, metrics."""

from __future__ import annotations

import time
from collections import deque

import numpy as np
from stable_baselines3.common.callbacks import BaseCallback

from icarus_vision.policy.config import CurriculumConfig


def episode_success(info: dict) -> bool:
    """An episode succeeds when every gate was passed without a crash."""
    return bool(info.get("all_gates_passed")) and not info.get("crashed")


class CurriculumCallback(BaseCallback):
    """Promotes through ``stages`` gate counts when the success rate is high enough.

    Only episodes flown at the current stage's gate count enter the window (drones that were
    mid-episode at a promotion finish their old track first). Promotion happens when at least
    ``min_episodes`` such episodes were seen and the success rate over the last ``window`` of them
    reaches ``promote_success``; it is applied with ``env_method("set_num_gates", n)``.
    """

    def __init__(
        self, cfg: CurriculumConfig, stage: int = 0, verbose: int = 1, on_promote=None
    ) -> None:
        super().__init__(verbose)
        self.cfg = cfg
        self.stage = stage
        self.window: deque[bool] = deque(maxlen=cfg.window)
        self.on_promote = on_promote
        self.venv = None  # the VecEnv to configure; SB3's training env when left None

    def _apply(self) -> None:
        env = self.venv if self.venv is not None else self.training_env
        env.env_method("set_num_gates", self.num_gates)
        if self.cfg.difficulty is not None:
            env.env_method("set_difficulty", self.difficulty)

    @property
    def num_gates(self) -> int:
        return self.cfg.stages[self.stage]

    @property
    def difficulty(self) -> float | None:
        """Race-layout difficulty of the current stage (None: classic layouts)."""
        return self.cfg.difficulty_at(self.stage)

    def _on_training_start(self) -> None:
        self._apply()

    def record(self, info: dict) -> bool:
        """Count one finished episode; returns True when this promoted the curriculum."""
        if info.get("gates_total") != self.num_gates or info.get("replayed"):
            return False
        if self.cfg.difficulty is not None and info.get("difficulty") != self.difficulty:
            return False
        self.window.append(episode_success(info))
        rate = float(np.mean(self.window))
        if len(self.window) >= self.cfg.min_episodes and rate >= self.cfg.promote_success:
            if self.stage + 1 < len(self.cfg.stages):
                self.stage += 1
                self.window.clear()
                self._apply()
                if self.verbose:
                    layout = "" if self.difficulty is None else f", difficulty {self.difficulty:g}"
                    print(
                        f"curriculum: success {rate:.0%} -> stage {self.stage} ({self.num_gates} gates{layout})"
                    )
                if self.on_promote:
                    self.on_promote(self.stage)
                return True
        return False

    def success_rate(self) -> float:
        return float(np.mean(self.window)) if self.window else 0.0

    def _on_step(self) -> bool:
        for i in np.flatnonzero(self.locals["dones"]):
            self.record(self.locals["infos"][i])
        self.logger.record("curriculum/stage", self.stage)
        self.logger.record("curriculum/num_gates", self.num_gates)
        if self.difficulty is not None:
            self.logger.record("curriculum/difficulty", self.difficulty)
        self.logger.record("curriculum/success_rate", self.success_rate())
        return True


class RunningMeanStd:
    """Welford / Chan running mean and variance over every value ever added."""

    def __init__(self) -> None:
        self.count, self.mean, self.m2 = 0, 0.0, 0.0

    def update(self, x: np.ndarray) -> None:
        x = np.asarray(x, dtype=np.float64).ravel()
        n, mean = x.size, float(x.mean()) if x.size else 0.0
        if n == 0:
            return
        m2 = float(((x - mean) ** 2).sum())
        total = self.count + n
        delta = mean - self.mean
        self.mean += delta * n / total
        self.m2 += m2 + delta * delta * self.count * n / total
        self.count = total

    @property
    def var(self) -> float:
        return self.m2 / self.count if self.count else 1.0

    @property
    def std(self) -> float:
        return float(np.sqrt(self.var))


class RunningAdvantageNorm(BaseCallback):
    """Normalises each rollout's advantages with running statistics over all rollouts so far.

    Use with ``PPO(normalize_advantage=False)``. Runs after SB3 has computed the rollout's
    returns and advantages (``on_rollout_end``) and rewrites them in place.
    """

    def __init__(self) -> None:
        super().__init__()
        self.stats = RunningMeanStd()

    def _on_rollout_end(self) -> None:
        adv = self.model.rollout_buffer.advantages
        self.stats.update(adv)
        adv[...] = (adv - self.stats.mean) / (self.stats.std + 1e-8)
        self.logger.record("train/adv_running_mean", self.stats.mean)
        self.logger.record("train/adv_running_std", self.stats.std)

    def _on_step(self) -> bool:
        return True


class CriticWarmup(BaseCallback):
    """Trains only the value network until ``steps`` environment steps have been taken.

    A policy started from an exported actor meets a value network that knows nothing yet; the
    first PPO updates would follow its random advantages and undo what the actor knew. Freezing
    the actor (and its log-std) for the first rollouts lets the critic catch up.
    """

    def __init__(self, steps: int) -> None:
        super().__init__()
        self.steps = steps

    def _actor_params(self) -> list:
        pol = self.model.policy
        return [
            *pol.mlp_extractor.policy_net.parameters(),
            *pol.action_net.parameters(),
            pol.log_std,
        ]

    def _on_rollout_end(self) -> None:
        frozen = self.num_timesteps < self.steps
        for param in self._actor_params():
            param.requires_grad_(not frozen)
        self.logger.record("train/actor_frozen", float(frozen))

    def _on_training_end(self) -> None:
        for param in self._actor_params():
            param.requires_grad_(True)

    def _on_step(self) -> bool:
        return True


class ScheduledRate:
    """The learning rate :class:`Anneal` sets, as SB3's schedule: an object SB3 can pickle into
    each checkpoint (a bound method of the callback cannot be)."""

    def __init__(self, value: float) -> None:
        self.value = value

    def __call__(self, _progress_remaining: float) -> float:
        return self.value


class Anneal(BaseCallback):
    """Lowers the learning rate and the ceiling on the policy's log std linearly over the run.

    ``fraction()`` says how much of the run is done (0 to 1; the larger of its steps and its wall
    time where a time limit is set). Before each rollout and at the run's end the learning rate
    becomes ``lr0 + f (lr1 - lr0)`` and each action axis's log std at most ``start + f (std1 -
    start)``, ``start`` being its value when the run began (``std_start``, kept in the checkpoint
    so a resumed run goes on along the same line). ``lr1`` or ``std1`` None leaves that one alone.
    """

    def __init__(self, fraction, lr0: float, lr1: float | None, std1: float | None,
                 std_start: list[float] | None = None) -> None:  # fmt: skip
        super().__init__()
        self.fraction = fraction
        self.lr0, self.lr1, self.std1 = lr0, lr1, std1
        self.std_start = std_start
        self.rate = ScheduledRate(lr0)

    def _on_training_start(self) -> None:
        if self.std1 is not None and self.std_start is None:
            self.std_start = self.model.policy.log_std.detach().cpu().tolist()
        if self.lr1 is not None:
            self.model.lr_schedule = self.rate

    def _apply(self) -> None:
        import torch

        f = min(max(float(self.fraction()), 0.0), 1.0)
        if self.lr1 is not None:
            self.rate.value = self.lr0 + f * (self.lr1 - self.lr0)
        if self.std1 is not None:
            start = torch.as_tensor(self.std_start, dtype=torch.float32)
            ceiling = start + f * (self.std1 - start)
            log_std = self.model.policy.log_std
            with torch.no_grad():
                log_std.copy_(torch.minimum(log_std, ceiling.to(log_std.dtype)))
            self.logger.record("train/log_std_ceiling", float(ceiling.max()))

    def _on_rollout_start(self) -> None:
        self._apply()

    def _on_training_end(self) -> None:  # the saved model keeps to the ceiling too
        self._apply()

    def _on_step(self) -> bool:
        return True


class MetricsCallback(BaseCallback):
    """Keeps a wall-clock log of training (timesteps, success, return) for curves and the console."""

    def __init__(self, curriculum: CurriculumCallback, every: int = 200_000, progress=None) -> None:
        super().__init__()
        self.curriculum = curriculum
        self.every = every
        self.rows: list[dict] = []
        self.returns: deque[float] = deque(maxlen=200)
        self.term_sums: dict[str, deque] = {}  # named reward terms per episode, for TensorBoard
        self.progress = progress
        self._next = 0
        self._t0 = time.perf_counter()
        self.wall_offset = 0.0

    def _on_training_start(self) -> None:
        self._t0 = time.perf_counter()
        self._next = self.num_timesteps

    def elapsed(self) -> float:
        """Wall-clock seconds of training so far, including runs this one resumed."""
        return self.wall_offset + time.perf_counter() - self._t0

    def _on_step(self) -> bool:
        for i in np.flatnonzero(self.locals["dones"]):
            info = self.locals["infos"][i]
            ep = info.get("episode")
            if ep:
                self.returns.append(ep["r"])
            for term, value in info.get("episode_reward_terms", {}).items():
                self.term_sums.setdefault(term, deque(maxlen=200)).append(value)
        for term, values in self.term_sums.items():
            self.logger.record(f"reward/{term}", float(np.mean(values)))
        if self.progress is not None:
            self.progress(self.num_timesteps, self.curriculum)
        if self.num_timesteps >= self._next:
            self._next = self.num_timesteps + self.every
            self.rows.append(
                {
                    "wall_s": round(self.elapsed(), 2),
                    "timesteps": int(self.num_timesteps),
                    "stage": self.curriculum.stage,
                    "num_gates": self.curriculum.num_gates,
                    "success_rate": round(self.curriculum.success_rate(), 4),
                    "mean_return": round(float(np.mean(self.returns)), 3) if self.returns else None,
                }
            )
        return True
