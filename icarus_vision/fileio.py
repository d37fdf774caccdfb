"""Small file helpers shared by every stage: atomic writes so that Ctrl-C never leaves half a file."""

from __future__ import annotations

import json
import os
import tempfile
import tomllib
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def publish(tmp: str | os.PathLike, path: str | os.PathLike) -> None:
    """Give a finished temporary file the usual permissions and rename it over ``path``."""
    os.chmod(tmp, 0o666 & ~_umask())
    os.replace(tmp, path)


@contextmanager
def atomic_path(path: str | os.PathLike, suffix: str = ".tmp") -> Iterator[Path]:
    """A temporary file beside ``path`` (ending in ``suffix``) for a writer that takes a path:
    published over ``path`` when the block ends normally, deleted if it raises."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=suffix)
    os.close(fd)
    try:
        yield Path(tmp)
        publish(tmp, path)  # mkstemp makes 0600 files
    finally:
        Path(tmp).unlink(missing_ok=True)


def atomic_write_bytes(path: str | os.PathLike, data: bytes) -> None:
    """Write ``data`` to ``path`` atomically: a temporary file in the same folder, then rename."""
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)


def atomic_write_npz(path: str | os.PathLike, **arrays) -> None:
    """Write numpy ``arrays`` to an ``.npz`` file atomically, streamed to the temporary file (no
    copy of the arrays in memory); read it back with ``np.load(path, allow_pickle=False)``."""
    import numpy as np  # only this helper needs it

    with atomic_path(path) as tmp, open(tmp, "wb") as f:
        np.savez(f, **arrays)


def atomic_write_text(path: str | os.PathLike, text: str) -> None:
    """Write a UTF-8 text file atomically."""
    atomic_write_bytes(path, text.encode("utf-8"))


def atomic_write_json(path: str | os.PathLike, obj) -> None:
    """Write one JSON object atomically (indented, NaN refused so files stay standard JSON)."""
    atomic_write_text(path, json.dumps(obj, indent=2, allow_nan=False) + "\n")


def read_toml(path: str | os.PathLike, what: str, error: type[Exception] = ValueError) -> dict:
    """Parse a TOML file; a missing or malformed file raises ``error`` naming the file.

    Args:
        what: the kind of file, for the message ("track", "recipe", ...).
        error: exception class for both cases (a ValueError subclass or FileNotFoundError).
    """
    path = Path(path)
    if not path.is_file():
        raise (FileNotFoundError if error is FileNotFoundError else error)(
            f"{path}: {what} file not found"
        )
    try:
        return tomllib.loads(path.read_text())
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as e:
        cls = ValueError if error is FileNotFoundError else error
        raise cls(f"{path}: not a valid TOML file ({e})") from None


def check_output(path: str | os.PathLike | None, *, folder: bool = False) -> None:
    """Refuse, before any work starts, an output path that cannot be written.

    Args:
        path: a file to be written (``folder=False``) or a folder to be created; None is allowed.

    Raises:
        ValueError: the path (or, for a file, its folder) lies under an existing file, or is an
            existing folder where a file is expected (or the reverse), naming the path.
    """
    if path is None:
        return
    p = Path(path)
    if folder and p.exists() and not p.is_dir():
        raise ValueError(f"{p}: exists and is not a folder")
    if not folder and p.is_dir():
        raise ValueError(f"{p}: is a folder, expected a file path")
    for parent in p.parents if not folder else (p, *p.parents):
        if parent.exists():
            if not parent.is_dir():
                raise ValueError(f"{p}: cannot be written, {parent} is a file")
            if not os.access(parent, os.W_OK):
                raise ValueError(f"{p}: cannot be written, {parent} is not writable")
            return
