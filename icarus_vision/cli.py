"""The ``icarus-vision`` command line. Thin: parse, call one library function, print.

User errors (bad files, names, values) print one line to stderr and exit 1, without a traceback.
The commands are in ``icarus_vision/commands/``, one module each, imported at the bottom.
"""

from __future__ import annotations

import functools
import signal
import sys
from contextlib import ExitStack

import typer
from rich.console import Console
from rich.markup import escape
from rich.progress import Progress

app = typer.Typer(
    help="icarus-vision: vision-based autonomous drone racing.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
    # Markdown: a docstring's paragraphs reflow to the terminal's width instead of keeping the
    # source's line breaks, which cut sentences in the middle on narrow or wide terminals.
    rich_markup_mode="markdown",
)
console = Console()
err_console = Console(stderr=True)


def progress_reporter(stack: ExitStack, columns: tuple, transient: bool = False):
    """A ``progress(done, total)`` callback for the library's long work: a rich progress bar
    with ``columns``, entered on ``stack`` at the first report (so that bad input fails before
    any output); the work done by then counts from the start."""
    state: dict = {}

    def progress(done: int, total: int) -> None:
        if not state:
            bar = stack.enter_context(Progress(*columns, console=console, transient=transient))
            state["bar"], state["task"] = bar, bar.add_task("work", total=total, completed=done)
        else:
            state["bar"].update(state["task"], completed=done)

    return progress


def stop_on_sigterm() -> None:
    """Make SIGTERM (a scheduler or a session stopping the job) stop it as Ctrl-C does, so the
    command saves what it has before it exits."""

    def interrupt(signum, frame) -> None:
        raise KeyboardInterrupt

    signal.signal(signal.SIGTERM, interrupt)


def user_errors(fn):
    """Turn the library's user-facing exceptions into a one-line error and exit code 1."""

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        try:
            return fn(*args, **kwargs)
        except (ValueError, FileNotFoundError, RuntimeError) as e:
            err_console.print(
                f"[bold red]error:[/] {escape(str(e))}",
                markup=True,
                emoji=False,  # a path like DIR:x: stays as typed
                highlight=False,
                soft_wrap=True,
            )
            raise typer.Exit(1) from None
        except KeyboardInterrupt:
            err_console.print("interrupted")
            sys.exit(130)

    return wrapper


# Each command lives in its own module under icarus_vision/commands/ and registers itself on `app`.
from icarus_vision.commands import average_policy as _average_policy  # noqa: E402,F401
from icarus_vision.commands import build_detector as _build_detector  # noqa: E402,F401
from icarus_vision.commands import eval_detector as _eval_detector  # noqa: E402,F401
from icarus_vision.commands import eval_estimator as _eval_estimator  # noqa: E402,F401
from icarus_vision.commands import eval_policy as _eval_policy  # noqa: E402,F401
from icarus_vision.commands import gen_dataset as _gen_dataset  # noqa: E402,F401
from icarus_vision.commands import import_gates as _import_gates  # noqa: E402,F401
from icarus_vision.commands import plan as _plan  # noqa: E402,F401
from icarus_vision.commands import quantize_detector as _quantize_detector  # noqa: E402,F401
from icarus_vision.commands import race as _race  # noqa: E402,F401
from icarus_vision.commands import sweep as _sweep  # noqa: E402,F401
from icarus_vision.commands import tracks as _tracks  # noqa: E402,F401
from icarus_vision.commands import train_detector as _train_detector  # noqa: E402,F401
from icarus_vision.commands import train_policy as _train_policy  # noqa: E402,F401
from icarus_vision.commands import train_refiner as _train_refiner  # noqa: E402,F401
from icarus_vision.commands import train_rescorer as _train_rescorer  # noqa: E402,F401
from icarus_vision.commands import train_zoom as _train_zoom  # noqa: E402,F401


def main() -> None:
    app()


if __name__ == "__main__":
    main()
