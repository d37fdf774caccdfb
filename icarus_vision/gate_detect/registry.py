"""Named image detectors: ``make_detector("opencv")``, ``make_detector("cnn:path/to/weights")``.

Detector modules register a factory under a name; the part of a spec after the first ``:`` is passed
to the factory as its argument (a weights path, for example). The oracle is not in the registry: it
needs the true pose and track, so the code that owns the simulator builds it.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable

from icarus_vision.gate_detect.base import Detector

_FACTORIES: dict[str, Callable[[str | None], Detector]] = {}
_BUILT_IN = {
    "opencv": "icarus_vision.gate_detect.opencv_detector",
    "cnn": "icarus_vision.gate_detect.cnn",
}
"""Detector modules imported on first use (importing one registers its factory)."""


def _load_built_in(name: str | None = None) -> None:
    for key, module in _BUILT_IN.items():
        if (name is None or key == name) and key not in _FACTORIES:
            importlib.import_module(module)


def register_detector(name: str, factory: Callable[[str | None], Detector]) -> None:
    """Make ``make_detector(name[:arg])`` call ``factory(arg)`` (arg None when not given)."""
    _FACTORIES[name] = factory


def available_detectors() -> tuple[str, ...]:
    """Names of the registered image detectors (the built-in ones included)."""
    _load_built_in()
    return tuple(sorted(_FACTORIES))


def parse_spec(spec: str) -> tuple[str, str | None]:
    """``"cnn:PATH"`` -> ("cnn", "PATH"); ``"opencv"`` -> ("opencv", None)."""
    name, _, arg = str(spec).partition(":")
    return name.strip(), (arg or None)


def make_detector(spec: str) -> Detector:
    """The registered detector named by ``spec`` (``NAME`` or ``NAME:ARG``).

    Raises:
        ValueError: no detector of that name is registered; a corrupt checkpoint.
        FileNotFoundError: a checkpoint path that does not exist.
    """
    name, arg = parse_spec(spec)
    _load_built_in(name)
    if name not in _FACTORIES:
        known = ", ".join((*available_detectors(), "oracle"))
        raise ValueError(f"unknown detector {name!r}; choose one of {known}")
    return _FACTORIES[name](arg)
