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


def convert(hint, value, key: str, where: str, error: type[Exception] = ValueError):
    """Check one TOML/JSON value against a field's annotated type and convert it (lists become
    tuples); ``error`` says ``where: key: must be ...`` otherwise.

    Handles str (non-empty), bool, int, float (finite), ``X | None``, fixed and variadic tuples
    (variadic ones non-empty); a dataclass or other type is returned unchanged for its own loader.
    """

    def fail(msg: str) -> Exception:
        return error(f"{where}: {key}: {msg}")

    origin, args = typing.get_origin(hint), typing.get_args(hint)
    if origin in (types.UnionType, typing.Union):
        if value is None and type(None) in args:
            return None
        options = [a for a in args if a is not type(None)]
        if len(options) == 1:
            return convert(options[0], value, key, where, error)
        for opt in options:
            try:
                return convert(opt, value, key, where, error)
            except error:
                continue
        raise fail(f"must be {' or '.join(map(str, options))}, got {_show(value)}")
    if hint is str:
        if not isinstance(value, str) or not value:
            raise fail(f"must be a non-empty string, got {_show(value)}")
        return value
    if hint is bool:
        if not isinstance(value, bool):
            raise fail(f"must be true or false, got {_show(value)}")
        return value
    if hint is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise fail(f"must be an integer, got {_show(value)}")
        return value
    if hint is float:
        if (
            isinstance(value, bool)
            or not isinstance(value, int | float)
            or not math.isfinite(value)
        ):
            raise fail(f"must be a finite number, got {_show(value)}")
        return float(value)
    if origin is tuple:
        if not isinstance(value, list | tuple):
            raise fail(f"must be a list, got {_show(value)}")
        if len(args) == 2 and args[1] is Ellipsis:
            if not value:
                raise fail("must not be empty")
            return tuple(convert(args[0], x, key, where, error) for x in value)
        if len(value) != len(args):
            raise fail(f"must have {len(args)} values, got {_show(value)}")
        if all(a is int for a in args) and not all(
            isinstance(x, int) and not isinstance(x, bool) for x in value
        ):
            raise fail(f"must be integers, got {_show(value)}")
        return tuple(convert(a, x, key, where, error) for a, x in zip(args, value, strict=True))
    return value


def check_table(
    cls, table, where: str, error: type[Exception] = ValueError, prefix: str = ""
) -> dict:
    """Check a TOML/JSON table against the fields of dataclass ``cls``.

    Unknown keys and values of the wrong type raise ``error`` naming ``where`` and the key
    (``prefix`` + field name, e.g. ``poses.distance``); values are converted by ``convert``.
    Nested dataclass fields are returned as they are, for the caller to build. Ranges stay with
    each configuration's own validation.

    Returns:
        The keyword arguments for ``cls`` (only the keys present).
    """
    require_table(table, f"{where}: {prefix.rstrip('.')}" if prefix else where, error)
    hints = typing.get_type_hints(cls)
    known = {f.name for f in fields(cls)}
    unknown = sorted(set(table) - known)
    if unknown:
        raise error(
            f"{where}: {prefix}{unknown[0]}: unknown key(s) {unknown}; allowed: {sorted(known)}"
        )
    return {k: convert(hints[k], v, f"{prefix}{k}", where, error) for k, v in table.items()}


__all__ = ["check_table", "convert", "require_list", "require_table"]
