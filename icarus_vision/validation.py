"""The one validation layer of the file loaders: tables, lists and dataclass fields checked against
their annotated types, unknown keys refused, every message naming the file and the key.

Each loader passes its own error class (``TrackError``, ``QuadError``, ``ValueError``...), so a
caller catches what it always caught; the CLI turns any of them into a one-line error.
"""

from __future__ import annotations

import math
import types
import typing
from dataclasses import fields


def require_table(value, where: str, error: type[Exception] = ValueError) -> dict:
    """``value`` if it is a table (dict), else ``error`` naming ``where``."""
    if not isinstance(value, dict):
        raise error(f"{where}: expected a table, got {_show(value)}")
    return value


def require_list(value, where: str, error: type[Exception] = ValueError) -> list:
    """``value`` if it is a list, else ``error`` naming ``where``."""
    if not isinstance(value, list):
        raise error(f"{where}: expected a list, got {_show(value)}")
    return value


def _show(value) -> str:
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def _fits_number(v, kind) -> bool:
    if isinstance(v, bool):
        return False
    if kind is int:
        return isinstance(v, int)
    return isinstance(v, int | float) and math.isfinite(v)


def _fits(value, hint) -> bool:
    origin = typing.get_origin(hint)
    if origin in (types.UnionType, typing.Union):
        return any(_fits(value, h) for h in typing.get_args(hint))
    if hint is type(None):
        return value is None
    if hint is bool:
        return isinstance(value, bool)
    if hint in (int, float):
        return _fits_number(value, hint)
    if hint is str:
        return isinstance(value, str)
    if origin is tuple:
        args = typing.get_args(hint)
        if not isinstance(value, list | tuple):
            return False
        if len(args) == 2 and args[1] is Ellipsis:
            return all(_fits(v, args[0]) for v in value)
        return len(value) == len(args) and all(
            _fits(v, a) for v, a in zip(value, args, strict=True)
        )
    return True  # nested dataclasses and other types are checked by their own loader


def _describe(hint) -> str:
    origin = typing.get_origin(hint)
    if origin in (types.UnionType, typing.Union):
        return " or ".join(_describe(h) for h in typing.get_args(hint))
    if hint is type(None):
        return "none"
    if origin is tuple:
        args = typing.get_args(hint)
        count = "" if len(args) == 2 and args[1] is Ellipsis else f"{len(args)} "
        return f"a list of {count}{_PLURAL.get(args[0], 'values')}"
    names = {bool: "true or false", int: "an integer", float: "a finite number", str: "a string"}
    return names.get(hint, getattr(hint, "__name__", str(hint)))


_PLURAL = {int: "integers", float: "finite numbers", str: "strings"}


def check_table(cls, table, where: str, error: type[Exception] = ValueError) -> dict:
    """Check a TOML/JSON table against the fields of dataclass ``cls``.

    Unknown keys and values of the wrong type raise ``error`` naming ``where`` and the key; lists
    become tuples. Nested dataclass fields are left to their own check. Ranges stay with each
    config's own validation.

    Returns:
        The keyword arguments for ``cls`` (only the keys present).
    """
    require_table(table, where, error)
    hints = typing.get_type_hints(cls)
    known = {f.name for f in fields(cls)}
    unknown = sorted(set(table) - known)
    if unknown:
        raise error(f"{where}: unknown key(s) {unknown}; allowed: {sorted(known)}")
    out = {}
    for key, value in table.items():
        if not _fits(value, hints[key]):
            raise error(f"{where}: {key} must be {_describe(hints[key])}, got {_show(value)}")
        out[key] = tuple(value) if isinstance(value, list) else value
    return out


__all__ = ["check_table", "require_list", "require_table"]
