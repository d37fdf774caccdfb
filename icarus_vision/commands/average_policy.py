"""`icarus-vision average-policy`: the mean of a run's last evaluated policies (weight averaging)."""

from __future__ import annotations

from pathlib import Path

import typer
from rich.markup import escape

from icarus_vision.cli import app, console, user_errors


def last_evaluated(run: Path, last: int) -> list[Path]:
    """The ``last`` policies a training run exported at its evaluations (``RUN/evaluated/``),
    oldest first."""
    found = sorted((run / "evaluated").glob("*.safetensors"))
    if not found:
        raise FileNotFoundError(
            f"{run / 'evaluated'}: no evaluated policies (train-policy writes one per evaluation)"
        )
    if last > len(found):
        raise ValueError(f"{run}: --last {last}, but the run evaluated {len(found)} policies")
    return [p.with_suffix("") for p in found[-last:]]


@app.command("average-policy")
@user_errors
def average_policy_cmd(
    run: Path = typer.Argument(..., help="train-policy output folder (its evaluated/ policies)."),
    last: int = typer.Option(5, min=1, help="Average this many of the run's last evaluations."),
    out: Path = typer.Option(
        None, help="Policy path to write (default: RUN/average, i.e. average.safetensors/.json)."
    ),
) -> None:
    """Average the weights of a training run's last evaluated policies into one policy.

    A run on a plateau swings from one evaluation to the next; the mean of its last policies'
    weights (stochastic weight averaging) flies like a steady one. Fly it with `race --policy
    RUN/average` or measure it with `eval-policy`. Deterministic: the same run gives the same
    bytes.
    """
    from icarus_vision.policy.export import average_policies

    paths = last_evaluated(run, last)
    dest = average_policies(paths, out or run / "average", {"name": "average", "last": last})
    console.print(
        f"average of {len(paths)} policies ({escape(paths[0].name)} … {escape(paths[-1].name)}) "
        f"written to {escape(str(dest))}",
        highlight=False,
    )
