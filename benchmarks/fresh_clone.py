"""A newcomer's first hour, measured: clone, `make test`, then the first `make race`.

    python3 benchmarks/fresh_clone.py [--repo .] [--json PATH]

Clones the repository's HEAD into a temporary folder (no .venv, no numba cache), times `make test`
(creates .venv, installs, compiles the detector, runs the suite) and then `make race`, and reports
the real-time factor that first race printed in its report.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import tempfile
import time
from pathlib import Path


def _timed(cmd: list[str], cwd: Path) -> tuple[float, subprocess.CompletedProcess]:
    t0 = time.perf_counter()
    res = subprocess.run(cmd, cwd=cwd, capture_output=True, text=True)
    return time.perf_counter() - t0, res


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repo", default=".")
    ap.add_argument("--json", default=None)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        clone = Path(tmp) / "clone"
        subprocess.run(
            ["git", "clone", "-q", str(Path(args.repo).resolve()), str(clone)], check=True
        )
        test_s, test = _timed(["make", "test"], clone)
        race_s, race = _timed(["make", "race", "ARGS=--no-video --out runs/first-race"], clone)
        report = (
            json.loads((clone / "runs/first-race/report.json").read_text())
            if race.returncode == 0
            else {}
        )
        tail = test.stdout.strip().splitlines()[-1] if test.stdout.strip() else ""
    out = {
        "make_test_s": round(test_s, 1), "make_test_ok": test.returncode == 0, "pytest": tail,
        "make_race_s": round(race_s, 1), "make_race_ok": race.returncode == 0,
        "first_race_realtime_factor": report.get("realtime_factor"),
        "first_race_policy": report.get("policy"), "first_race_finished": report.get("finished"),
    }  # fmt: skip
    print(json.dumps(out, indent=1))
    if args.json:
        Path(args.json).write_text(json.dumps(out, indent=1) + "\n")


if __name__ == "__main__":
    main()
