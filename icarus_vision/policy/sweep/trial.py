"""One sweep trial: a normal ``train-policy`` run in ``OUT/trials/<id>/`` that reports to Ray Tune.

The trial trains with the sampled settings for its wall-clock budget; ``reports`` times along the
way (and at the end) it evaluates the current policy on the objective's random tracks and reports
``objective`` to Tune, whose scheduler (ASHA) may stop it there. A trial restarted by
``sweep --resume`` continues its run from the last checkpoint.
"""

from __future__ import annotations

import time
from pathlib import Path

from icarus_vision.fileio import atomic_write_json
from icarus_vision.policy.sweep.space import Objective, SearchSpace, decode

STARTED = "sweep_started.json"
"""Written into the trial's folder when its training starts."""
STAGE_TIE_BREAK = 1e-3
"""Objective added per curriculum stage reached: orders trials of equal success by their stage."""


def objective_value(metric: str, success: float, lap_per_gate_s: float | None, stage: int) -> float:
    """The number a sweep maximises.

    ``success``: success rate + 0.001 × curriculum stage; ``speed``: success rate − 0.1 × median
    lap per gate in s (1 s when nothing finished), the rule ``train-policy`` picks its best model by.
    """
    if metric == "speed":
        lap = 1.0 if lap_per_gate_s is None else lap_per_gate_s
        return success - 0.1 * lap
    return success + STAGE_TIE_BREAK * stage


def _evaluate(model, cfg, objective: Objective, seed: int):
    from icarus_vision.policy.train import evaluate_model

    return evaluate_model(
        model, cfg, objective.gates, objective.episodes, seed, objective.difficulty
    )


def _reporter(cfg, objective: Objective, budget_s: float, reports: int, seed: int, trial_dir: Path):
    """An SB3 callback factory: evaluate and ``tune.report`` at each ``budget_s / reports``."""
    from ray import tune
    from stable_baselines3.common.callbacks import BaseCallback

    class Report(BaseCallback):
        def __init__(self, curriculum, elapsed) -> None:
            super().__init__()
            self.curriculum, self.elapsed = curriculum, elapsed
            self.every = budget_s / reports
            self.next = self.every * (1 + int(elapsed() / self.every))

        def _on_training_start(self) -> None:
            # when the trial began to train (the sweep benchmark's time to the first trial)
            atomic_write_json(trial_dir / STARTED, {"time": time.time()})

        def _on_step(self) -> bool:
            # the last report is the final one, after the run has saved its policy
            if self.elapsed() >= self.next and self.next < budget_s - 0.5 * self.every:
                self.next += self.every
                report(self.model, self.curriculum, self.elapsed(), final=False)
            return True

    def report(model, curriculum, elapsed_s: float, final: bool) -> None:
        ev = _evaluate(model, cfg, objective, seed + 20_000 + int(model.num_timesteps))
        stage = int(curriculum.stage)
        tune.report({
            "objective": objective_value(objective.metric, ev.success, ev.lap_per_gate_s, stage),
            "success": ev.success, "lap_per_gate_s": ev.lap_per_gate_s, "stage": stage,
            "num_gates": int(curriculum.num_gates), "timesteps": int(model.num_timesteps),
            "minutes": elapsed_s / 60.0, "final": final, "trial_dir": str(trial_dir),
        })  # fmt: skip

    return Report, report


def run_trial(params: dict, *, space: SearchSpace, out: str, minutes: float, reports: int,
              seed: int) -> None:  # fmt: skip
    """The Ray Tune function trainable (``params``: one sample of the search space)."""
    import torch
    from ray import tune

    from icarus_vision.policy.train import train_policy

    torch.set_num_threads(1)
    trial_id = tune.get_context().get_trial_id()
    trial_dir = Path(out) / "trials" / trial_id
    values = decode(space, params)
    cfg = space.trial_config(values)
    if "ppo.torch_threads" not in values:  # one core per trial
        from dataclasses import replace

        cfg = replace(cfg, ppo=replace(cfg.ppo, torch_threads=1))
    resume = (trial_dir / "checkpoints" / "last.zip").is_file()
    budget_s = minutes * 60.0
    factory, report = _reporter(cfg, space.objective, budget_s, reports, seed, trial_dir)
    made = []

    def callbacks(curriculum, elapsed):
        made.append(factory(curriculum, elapsed))
        return made

    train_policy(cfg, trial_dir, seed=seed, resume=resume, max_wall_s=budget_s,
                 callbacks=callbacks, verbose=0, timesteps=10**12)  # fmt: skip
    cb = made[0]
    report(cb.model, cb.curriculum, cb.elapsed(), final=True)
