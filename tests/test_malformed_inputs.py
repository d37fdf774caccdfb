"""Every command over a corpus of malformed files: a one-line error, a non-zero exit, no traceback,
and an existing output file left as it was."""

from __future__ import annotations

import json
import shutil

import pytest
from typer.testing import CliRunner

from icarus_vision.cli import app
from icarus_vision.policy.pilots import default_policy_path


def detector_dir():
    from importlib import resources

    return resources.files("icarus_vision").joinpath("models/detector")


runner = CliRunner()
GOOD_TRACK = 'name = "t"\n[start]\npos = [0.0, 0.0, 0.2]\n[[gates]]\npos = [5.0, 0.0, 2.0]\n'
TRACKS = {
    "start-scalar": 'name = "t"\nstart = 5\n[[gates]]\npos = [5.0, 0.0, 2.0]\n',
    "gates-scalar": 'name = "t"\ngates = 5\n[start]\npos = [0.0, 0.0, 0.2]\n',
    "defaults-scalar": GOOD_TRACK.replace('name = "t"\n', 'name = "t"\ndefaults = 5\n'),
    "bounds-scalar": GOOD_TRACK.replace('name = "t"\n', 'name = "t"\nbounds = 5\n'),
    "gate-scalar": 'name = "t"\ngates = [5]\n[start]\npos = [0.0, 0.0, 0.2]\n',
    "laps-zero": GOOD_TRACK.replace('name = "t"\n', 'name = "t"\nlaps = 0\n'),
    "not-toml": "name = \n",
}
QUADS = {
    "drag-strings": 'drag = ["a", 1, 2]\n',
    "inertia-scalar": "inertia = 5\n",
    "uptilt-string": '[camera]\nuptilt_deg = "x"\n',
    "name-number": "name = 5\n",
    "camera-scalar": "camera = 5\n",
}
CONFIGS = {
    "mass-pct": "[randomization]\nmass_pct = 5\n",
    "wind-negative": "[randomization]\nwind_mps = -1.0\n",
    "sigma-negative": "[perception]\nsigma_base_m = -0.1\n",
    "miss-base": "[perception]\nmiss_base = 3\n",
    "timesteps-fraction": "total_timesteps = 1.5\n",
    "episode-negative": "max_episode_s = -2.0\n",
    "ppo-scalar": "ppo = 5\n",
}
POLICIES = {"list": [], "no-hidden": {"format": "icarus-policy-v1"}}
DETECTORS = {"list": [], "string": "x", "empty": {}}


def _cases():
    for name in TRACKS:
        yield f"track-{name}", "track", name
    for name in QUADS:
        yield f"quad-{name}", "quad", name
    for name in CONFIGS:
        yield f"config-{name}", "config", name
    for name in POLICIES:
        yield f"policy-{name}", "policy", name
    for name in DETECTORS:
        yield f"detector-{name}", "detector", name


def _commands(kind: str, path: str, out: str) -> list[list[str]]:
    race = ["race", "--detector", "oracle", "--no-video", "--json", out]
    if kind == "track":
        return [
            [*race, "--track", path],
            ["plan", "--track", path, "--json", out],
            ["eval-policy", "--track", path, "--episodes", "1", "--json", out],
            ["eval-estimator", "--track", path, "--detector", "oracle", "--json", out],
        ]
    if kind == "quad":
        return [
            [*race, "--track", "single-gate", "--quad", path],
            ["plan", "--track", "single-gate", "--quad", path, "--json", out],
        ]
    if kind == "config":
        return [["train-policy", "--config", path, "--timesteps", "64"]]
    if kind == "detector":
        return [
            [
                "race",
                "--track",
                "single-gate",
                "--detector",
                f"cnn:{path}",
                "--no-video",
                "--json",
                out,
            ]
        ]
    return [
        [*race, "--track", "single-gate", "--policy", path],
        ["eval-policy", "--policy", path, "--episodes", "1", "--json", out],
    ]


@pytest.mark.parametrize("case, kind, name", list(_cases()), ids=[c[0] for c in _cases()])
def test_malformed_input_gives_one_line_error(tmp_path, monkeypatch, case, kind, name):
    monkeypatch.chdir(tmp_path)
    if kind == "detector":
        shutil.copytree(detector_dir(), tmp_path / "det")
        (tmp_path / "det" / "detector.json").write_text(json.dumps(DETECTORS[name]))
        path = str(tmp_path / "det")
    elif kind == "policy":
        shutil.copy(default_policy_path(), tmp_path / "p.safetensors")
        (tmp_path / "p.json").write_text(json.dumps(POLICIES[name]))
        path = str(tmp_path / "p.safetensors")
    else:
        text = {"track": TRACKS, "quad": QUADS, "config": CONFIGS}[kind][name]
        (tmp_path / "in.toml").write_text(text)
        path = str(tmp_path / "in.toml")
    out = tmp_path / "existing.json"
    out.write_text('{"keep": true}\n')
    for args in _commands(kind, path, str(out)):
        res = runner.invoke(app, args)
        assert res.exit_code != 0, (args, res.output)
        assert res.exception is None or isinstance(res.exception, SystemExit), repr(res.exception)
        assert "Traceback" not in res.output
        assert res.output.strip().startswith("error:") or "Error" in res.output, res.output
        assert out.read_text() == '{"keep": true}\n'
