"""``run_sweep``: train-policy trials proposed by Optuna (TPE), run and early-stopped by Ray Tune.

Ray starts embedded on this machine (one trial per core) unless ``address`` joins a cluster. The
sweep folder holds ``sweep.json`` (its settings) and ``space.toml`` (the search space as given),
``tune/`` (Ray Tune's experiment state, what ``resume`` restores), ``trials/<id>/`` (each trial's
train-policy run), and the results: ``trials.json``, ``results.csv``, ``best.toml`` and the plots,
rewritten as each trial ends.
"""

from __future__ import annotations

import json
import shutil
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from ray.tune import Callback

from icarus_vision.fileio import atomic_write_json
from icarus_vision.policy.sweep.report import write_results
from icarus_vision.policy.sweep.space import SearchSpace, encode_point, load_space, to_tune
from icarus_vision.policy.sweep.trial import run_trial
from icarus_vision.ray_runtime import start_ray

SETTINGS = "sweep.json"
SPACE = "space.toml"
TRIALS = "trials.json"
GRACE_FRACTION = 0.25
"""ASHA stops no trial before this fraction of its budget."""
REDUCTION_FACTOR = 2
"""ASHA keeps the best 1/2 of the trials at each of its milestones."""


@dataclass
class SweepState:
    """What the progress view shows: one entry per trial, by id."""

    trials: dict[str, dict] = field(default_factory=dict)
    started: float = field(default_factory=time.time)

    def count(self, status: str) -> int:
        return sum(t["status"] == status for t in self.trials.values())

    def best(self) -> dict | None:
        """The done or early-stopped trial with the highest objective (a failed one never)."""
        scored = [t for t in self.trials.values()
                  if t.get("objective") is not None and t["status"] != "failed"]  # fmt: skip
        return max(scored, key=lambda t: t["objective"]) if scored else None


def _record(state: SweepState, space: SearchSpace, trial, status=None, error=None) -> None:
    """Update the state's entry of ``trial`` from its last result."""
    r = trial.last_result or {}
    t = state.trials.setdefault(trial.trial_id, {"id": trial.trial_id, "status": "running"})
    t["params"] = {k: v for k, v in trial.config.items() if k in space.search}
    if "objective" in r:
        t.update({k: r.get(k) for k in ("objective", "success", "lap_per_gate_s", "stage",
                                        "timesteps", "minutes")})  # fmt: skip
        t["final"] = bool(r.get("final"))
    if status is not None:
        t["status"] = status
        t["ended"] = time.time()
    if error is not None:
        t["error"] = error


class ProgressCallback(Callback):
    """Runs in the sweep's process: keeps ``state``, the result files and the view current."""

    def __init__(self, state: SweepState, out: Path, space: SearchSpace, update) -> None:
        self.state, self.out, self.space, self.update = state, out, space, update

    def __getstate__(self) -> dict:
        return {}  # Tune pickles its run config; this process's view does not travel with it

    def __setstate__(self, d: dict) -> None:
        self.state = self.out = self.space = self.update = None  # inert until replaced

    def _changed(self) -> None:
        if self.state is None:
            return
        atomic_write_json(
            self.out / TRIALS, {"started": self.state.started, "trials": self.state.trials}
        )
        if self.update is not None:
            self.update(self.state)

    def _ended(self, trial, status: str, error: str | None = None) -> None:
        if self.state is None:
            return
        _record(self.state, self.space, trial, status, error)
        write_results(self.out, self.space, self.state)
        self._changed()

    def on_trial_start(self, iteration, trials, trial, **info):
        if self.state is not None:
            _record(self.state, self.space, trial, "running")
            self.state.trials[trial.trial_id].setdefault("began", time.time())
            self._changed()

    def on_trial_result(self, iteration, trials, trial, result, **info):
        if self.state is not None:
            _record(self.state, self.space, trial)
            self._changed()

    def on_trial_complete(self, iteration, trials, trial, **info):
        done = bool((trial.last_result or {}).get("final"))
        self._ended(trial, "done" if done else "stopped early")

    def on_trial_error(self, iteration, trials, trial, **info):
        self._ended(trial, "failed", _error_line(trial))


def _error_line(trial) -> str:
    """The last line of a failed trial's traceback (what a user needs to see first)."""
    try:
        text = Path(trial.error_file).read_text() if trial.error_file else ""
    except OSError:
        text = ""
    lines = [ln.strip() for ln in text.strip().splitlines() if ln.strip()]
    return lines[-1] if lines else "failed"


def _check_folder(out: Path, resume: bool) -> None:
    if resume:
        if not (out / SETTINGS).is_file():
            raise ValueError(
                f"{out}: no sweep to resume (no {SETTINGS}); start one without --resume"
            )
    elif out.exists() and any(out.iterdir()):
        what = "holds a sweep" if (out / SETTINGS).is_file() else "is not empty"
        raise ValueError(f"{out}: {what}; pass --resume to continue it, or choose another --out")


def run_sweep(
    space_path: str | Path | None,
    out: str | Path,
    *,
    trials: int = 8,
    trial_minutes: float = 10.0,
    reports: int = 6,
    address: str | None = None,
    resume: bool = False,
    seed: int = 0,
    update: Callable[[SweepState], None] | None = None,
) -> SweepState:
    """Run (or resume) a sweep; returns the state of every trial.

    Args:
        space_path: the search-space TOML (:mod:`.space`); with ``resume`` the sweep's own copy is
            used and this may be None.
        out: the sweep folder (created; a folder holding anything is refused without ``resume``).
        trials: trials in all (Optuna's first ten are random draws, TPE after).
        trial_minutes: wall-clock training budget of each trial.
        reports: objective evaluations per trial (ASHA's decision points).
        address: a Ray cluster's address (``ray start --head`` prints it); None: Ray starts here.
        seed: Optuna's sampler seed and every trial's training seed.
        update: called with the state whenever a trial starts, reports or ends (progress view).
    """
    import optuna
    from ray import tune
    from ray.tune.schedulers import ASHAScheduler
    from ray.tune.search.optuna import OptunaSearch

    optuna.logging.set_verbosity(optuna.logging.WARNING)
    out = Path(out).resolve()
    _check_folder(out, resume)
    if resume:
        settings = json.loads((out / SETTINGS).read_text())
        space = load_space(out / SPACE)
        trials, trial_minutes = settings["trials"], settings["trial_minutes"]
        reports, seed = settings["reports"], settings["seed"]
    else:
        if trials < 1 or trial_minutes <= 0 or reports < 1:
            raise ValueError("trials and reports must be >= 1 and trial_minutes > 0")
        space = load_space(space_path)
        out.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(space_path, out / SPACE)
        atomic_write_json(out / SETTINGS, {"trials": trials, "trial_minutes": trial_minutes,
                                           "reports": reports, "seed": seed,
                                           "space": str(space_path)})  # fmt: skip
    state = SweepState()
    if resume and (out / TRIALS).is_file():
        saved = json.loads((out / TRIALS).read_text())
        state.started, state.trials = saved["started"], saved["trials"]
    start_ray(address)
    trainable = tune.with_resources(
        tune.with_parameters(
            run_trial, space=space, out=str(out), minutes=trial_minutes, reports=reports, seed=seed
        ),  # fmt: skip
        {"cpu": 1},
    )
    run_config = tune.RunConfig(
        name="tune",
        storage_path=str(out),
        verbose=0,
        failure_config=tune.FailureConfig(max_failures=0, fail_fast=False),
        callbacks=[ProgressCallback(state, out, space, update)],
    )
    if resume:
        tuner = tune.Tuner.restore(str(out / "tune"), trainable, resume_unfinished=True,
                                   resume_errored=False)  # fmt: skip
        # Tune keeps the run config it was started with; the progress callback is this process's
        tuner._local_tuner._run_config.callbacks = run_config.callbacks
    else:
        search = OptunaSearch(
            points_to_evaluate=[encode_point(space, p) for p in space.start] or None, seed=seed
        )
        scheduler = ASHAScheduler(
            time_attr="minutes",
            max_t=trial_minutes,
            grace_period=trial_minutes * GRACE_FRACTION,
            reduction_factor=REDUCTION_FACTOR,
        )
        tuner = tune.Tuner(
            trainable,
            param_space=to_tune(space),
            tune_config=tune.TuneConfig(
                metric="objective",
                mode="max",
                search_alg=search,
                scheduler=scheduler,
                num_samples=trials,
            ),  # fmt: skip
            run_config=run_config,
        )
    tuner.fit()
    write_results(out, space, state)
    atomic_write_json(out / TRIALS, {"started": state.started, "trials": state.trials})
    return state
