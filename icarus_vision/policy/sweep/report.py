"""A sweep's results: ``results.csv``, ``best.toml`` and the plots, from the trials' records."""

from __future__ import annotations

import csv
import io
import math
import warnings
from pathlib import Path

from icarus_vision.fileio import atomic_path, atomic_write_text
from icarus_vision.policy.sweep.space import SearchSpace, best_config_dict, decode

RESULTS = "results.csv"
BEST = "best.toml"
PLOT = "objective.png"
IMPORTANCE = "importance.png"
COLUMNS = ("trial", "status", "objective", "success", "lap_per_gate_s", "stage", "timesteps",
           "minutes", "error")  # fmt: skip


def _rows(space: SearchSpace, state) -> list[dict]:
    rows = []
    for t in sorted(state.trials.values(), key=lambda t: t.get("began", math.inf)):
        row = {"trial": t["id"], "status": t["status"], "ended": t.get("ended")}
        row.update({k: t.get(k) for k in COLUMNS[2:]})
        row.update(decode(space, t.get("params", {})))
        rows.append(row)
    return rows


def _csv(rows: list[dict], params: list[str]) -> str:
    buf = io.StringIO()
    w = csv.DictWriter(buf, [*COLUMNS, *params], extrasaction="ignore", lineterminator="\n")
    w.writeheader()
    for r in rows:
        w.writerow({k: (str(v) if isinstance(v, list | tuple) else v) for k, v in r.items()})
    return buf.getvalue()


def write_results(out: Path, space: SearchSpace, state) -> None:
    """Rewrite results.csv, best.toml and the plots from ``state`` (atomically, each file)."""
    import tomli_w

    rows = _rows(space, state)
    params = list(space.search)
    atomic_write_text(out / RESULTS, _csv(rows, params))
    best = state.best()
    if best is not None:
        cfg = best_config_dict(space, decode(space, best["params"]))
        head = (f"# best trial {best['id']} of the sweep in {out.name}/: objective "
                f"{best['objective']:.4f} ({space.objective.metric}); a train-policy --config file\n")  # fmt: skip
        atomic_write_text(out / BEST, head + tomli_w.dumps(cfg))
    _plot_objective(out / PLOT, rows, state.started)
    _plot_importance(out / IMPORTANCE, space, state)


def _plot_objective(path: Path, rows: list[dict], started: float) -> None:
    from matplotlib.figure import Figure

    scored = [(i, r) for i, r in enumerate(rows) if r.get("objective") is not None]
    fig = Figure(figsize=(9, 3.6), dpi=100)
    a, b = fig.subplots(1, 2)
    colours = {"done": "tab:blue", "stopped early": "tab:orange", "running": "tab:gray"}
    for i, r in scored:
        c = colours.get(r["status"], "tab:red")
        a.scatter(i + 1, r["objective"], color=c)
    best = -math.inf
    xs, ys = [], []
    for i, r in scored:
        best = max(best, r["objective"])
        xs.append(i + 1)
        ys.append(best)
    a.step(xs, ys, where="post", color="k", lw=1, label="best so far")
    a.set(xlabel="trial", ylabel="objective", title="objective by trial")
    for label, c in colours.items():
        a.scatter([], [], color=c, label=label)
    a.legend(fontsize=7)
    ended = sorted((r["ended"] - started, r["objective"]) for r in _ended(rows))
    if ended:
        best, xs, ys = -math.inf, [], []
        for t, v in ended:
            best = max(best, v)
            xs.append(t / 60)
            ys.append(best)
        b.step(xs, ys, where="post", color="k")
        b.scatter(xs, [v for _, v in ended], color="tab:blue", s=12)
    b.set(xlabel="sweep wall-clock, min", ylabel="best objective", title="best by wall-clock")
    fig.tight_layout()
    with atomic_path(path, ".png") as tmp:
        fig.savefig(tmp)


def _ended(rows):
    return [r for r in rows if r.get("objective") is not None and r.get("ended") is not None]


def parameter_importances(space: SearchSpace, state) -> dict[str, float] | None:
    """Optuna's parameter importances over the trials with an objective (None: too few trials)."""
    import optuna
    from optuna.distributions import (
        CategoricalDistribution,
        FloatDistribution,
        IntDistribution,
    )

    dists = {}
    for key, d in space.search.items():
        if d.kind == "uniform":
            dists[key] = FloatDistribution(*d.values)
        elif d.kind == "loguniform":
            dists[key] = FloatDistribution(*d.values, log=True)
        elif d.kind == "int":
            dists[key] = IntDistribution(*d.values)
        else:
            dists[key] = CategoricalDistribution([str(v) for v in d.values])
    trials = []
    for t in state.trials.values():
        if t.get("objective") is None or t["status"] == "failed":
            continue
        params = {k: (str(v) if space.search[k].kind == "choice" else v)
                  for k, v in decode(space, t["params"]).items()}  # fmt: skip
        trials.append(optuna.trial.create_trial(params=params, distributions=dists,
                                                value=t["objective"]))  # fmt: skip
    if len(trials) < 3 or len(dists) < 1:
        return None
    optuna.logging.set_verbosity(optuna.logging.ERROR)
    study = optuna.create_study(direction="maximize")
    study.add_trials(trials)
    try:
        with warnings.catch_warnings():  # with few trials PED-ANOVA warns that all are equal
            warnings.simplefilter("ignore", UserWarning)
            evaluator = optuna.importance.PedAnovaImportanceEvaluator()
            return optuna.importance.get_param_importances(study, evaluator=evaluator)
    except (RuntimeError, ValueError):  # e.g. every objective equal
        return None


def _plot_importance(path: Path, space: SearchSpace, state) -> None:
    from matplotlib.figure import Figure

    imp = parameter_importances(space, state)
    fig = Figure(figsize=(6, max(2.0, 0.5 + 0.4 * len(space.search))), dpi=100)
    ax = fig.subplots()
    if imp:
        names = list(imp)[::-1]
        ax.barh(names, [imp[n] for n in names], color="tab:blue")
        ax.set(xlabel="importance (Optuna PED-ANOVA)", title="what mattered")
    else:
        ax.text(0.5, 0.5, "importances need 3 scored trials", ha="center", va="center")
        ax.set_axis_off()
    fig.tight_layout()
    with atomic_path(path, ".png") as tmp:
        fig.savefig(tmp)
