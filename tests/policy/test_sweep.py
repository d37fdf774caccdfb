"""``icarus-vision sweep``: the search-space file, and tiny sweeps through Ray Tune embedded here."""

from __future__ import annotations

import csv
import json
import os
import signal

import pytest
from typer.testing import CliRunner

from icarus_vision.cli import app
from icarus_vision.policy.config import load_train_config
from icarus_vision.policy.sweep import load_space, run_sweep
from icarus_vision.policy.sweep.space import decode, to_tune
from icarus_vision.policy.sweep.trial import objective_value

TINY_BASE = """
[base]
preset = "fast"
observation = "extended"  # as the shipped classic policy, which a trial may start from
checkpoint_every = 5000
eval_every = 5000
eval_episodes = 4
[base.ppo]
num_envs = 16
n_steps = 16
batch_size = 128
n_epochs = 1
net_arch = [64, 64]

[objective]
gates = 3
episodes = 8
"""


def write_space(tmp_path, body: str, name: str = "space.toml"):
    path = tmp_path / name
    path.write_text(body)
    return path


@pytest.mark.parametrize(
    "body, msg",
    [
        ('[search]\n"ppo.learnin_rate" = { uniform = [0.1, 0.2] }\n',
         "search.ppo.learnin_rate: not a train-policy setting (did you mean ppo.learning_rate"),
        ('[search]\n"ppo.learning_rate" = { gauss = [0.1, 0.2] }\n',
         "search.ppo.learning_rate: unknown distribution 'gauss'; use uniform, loguniform, int, choice"),
        ('[search]\n"ppo.learning_rate" = { uniform = [0.2, 0.1] }\n', "finite low < high"),
        ('[search]\n"ppo.learning_rate" = { loguniform = [0.0, 0.1] }\n', "loguniform needs low > 0"),
        ('[search]\n"ppo.n_epochs" = { int = [1.5, 4] }\n', "int needs integer bounds"),
        ('[search]\n"ppo.learning_rate" = { uniform = [-1.0, 0.1] }\n',
         "search.ppo.learning_rate: the value -1.0 is refused"),
        ('[search]\n"observation" = { choice = ["basic", "fancy"] }\n', "the value 'fancy' is refused"),
        ("[search]\n", "[search] must name at least one setting"),
        ('[serch]\n"ppo.gamma" = { uniform = [0.9, 0.99] }\n', "unknown table 'serch'"),
        ('[search]\n"ppo.gamma" = { uniform = [0.9, 0.99] }\n[objective]\nmetric = "laps"\n',
         "objective.metric must be one of success, speed"),
        ('[search]\n"ppo.gamma" = { uniform = [0.9, 0.99] }\n[[start]]\n"ppo.lambda" = 1\n',
         "start[0].ppo.lambda: not a searched setting"),
    ],
)  # fmt: skip
def test_space_errors_name_the_key_in_one_line(tmp_path, body, msg):
    path = write_space(tmp_path, body)
    with pytest.raises(ValueError) as e:
        load_space(path)
    assert msg in str(e.value) and str(path) in str(e.value) and "\n" not in str(e.value)
    res = CliRunner().invoke(app, ["sweep", "--space", str(path), "--out", str(tmp_path / "o")])
    assert res.exit_code == 1 and msg in " ".join(res.output.split())


def test_space_to_tune_and_back(tmp_path):
    path = write_space(tmp_path, TINY_BASE + """
[search]
"ppo.learning_rate" = { loguniform = [1e-4, 1e-2] }
"ppo.n_epochs" = { int = [2, 4] }
"ppo.net_arch" = { choice = [[16, 16], [32]] }
""")  # fmt: skip
    space = load_space(path)
    tune_space = to_tune(space)
    import random

    random.seed(0)
    for _ in range(20):
        sample = {k: v.sample() for k, v in tune_space.items()}
        values = decode(space, sample)
        assert 1e-4 <= values["ppo.learning_rate"] <= 1e-2
        assert values["ppo.n_epochs"] in (2, 3, 4)  # int bounds are inclusive
        assert values["ppo.net_arch"] in ([16, 16], [32])
        cfg = space.trial_config(values)
        assert cfg.ppo.net_arch == tuple(values["ppo.net_arch"]) and cfg.ppo.num_envs == 16


def test_objective():
    assert objective_value("success", 0.5, None, 2) == pytest.approx(0.502)
    assert objective_value("speed", 0.5, 0.8, 2) == pytest.approx(0.42)
    assert objective_value("speed", 0.0, None, 0) == pytest.approx(-0.1)


@pytest.mark.slow
def test_two_trials_one_failing(ray_here, tmp_path):
    path = write_space(tmp_path, TINY_BASE + """
[search]
"ppo.learning_rate" = { loguniform = [1e-4, 1e-2] }
"init" = { choice = ["none-such-policy.safetensors", "classic"] }

[[start]]
"ppo.learning_rate" = 1e-3
"init" = "none-such-policy.safetensors"

[[start]]
"ppo.learning_rate" = 1e-3
"init" = "classic"
""")  # fmt: skip
    out = tmp_path / "sweep"
    res = CliRunner().invoke(app, ["sweep", "--space", str(path), "--out", str(out), "--trials",
                                   "2", "--trial-minutes", "0.05", "--reports", "1"])  # fmt: skip
    assert res.exit_code == 0, res.output
    assert "best trial" in res.output and "1 done" in res.output and "1 failed" in res.output
    trials = json.loads((out / "trials.json").read_text())["trials"]
    status = sorted(t["status"] for t in trials.values())
    assert status == ["done", "failed"], trials
    failed = next(t for t in trials.values() if t["status"] == "failed")
    assert "none-such-policy.safetensors" in failed["error"]
    with (out / "results.csv").open() as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == 2 and {r["status"] for r in rows} == {"done", "failed"}
    assert all(r["ppo.learning_rate"] for r in rows)
    done = next(t for t in trials.values() if t["status"] == "done")
    run = out / "trials" / done["id"]
    assert (run / "policy.safetensors").is_file() and (run / "tb").is_dir()
    cfg = load_train_config(out / "best.toml")  # train-policy --config reads it as it is
    assert cfg.init == "classic" and cfg.ppo.num_envs == 16
    assert (out / "objective.png").read_bytes()[:4] == b"\x89PNG"
    assert "ended" not in rows[0]  # a plotting field, not a column
    # a second sweep into the same folder is refused without --resume
    with pytest.raises(ValueError, match="holds a sweep; pass --resume"):
        run_sweep(path, out, trials=2, trial_minutes=0.05)


@pytest.mark.slow
def test_interrupted_sweep_resumes_without_rerunning_finished_trials(ray_here, tmp_path):
    path = write_space(tmp_path, TINY_BASE + """
[search]
"ppo.learning_rate" = { loguniform = [1e-4, 1e-2] }
""")  # fmt: skip
    out = tmp_path / "sweep"
    sent = []

    def interrupt_after_first(state):  # Ctrl-C once a trial has finished
        if state.count("done") >= 1 and not sent:
            sent.append(True)
            os.kill(os.getpid(), signal.SIGINT)

    first = run_sweep(
        path, out, trials=4, trial_minutes=0.05, reports=1, update=interrupt_after_first
    )
    finished = {k for k, t in first.trials.items() if t["status"] == "done"}
    assert sent and 1 <= len(finished) < 4
    stamps = {k: (out / "trials" / k / "policy.safetensors").stat().st_mtime_ns for k in finished}
    second = run_sweep(None, out, resume=True)
    assert sum(t["status"] == "done" for t in second.trials.values()) == 4
    for k, mtime in stamps.items():  # the finished trials were not run again
        assert (out / "trials" / k / "policy.safetensors").stat().st_mtime_ns == mtime
    with (out / "results.csv").open() as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == 4
    assert json.loads((out / "sweep.json").read_text())["trials"] == 4
