"""Named image detectors: ``make_detector("opencv")``, ``make_detector("cnn:path/to/weights")``.

Detector modules register a factory under a name; the part of a spec after the first ``:`` is passed
to the factory as its argument (a weights path, for example), and keyword settings after it
(``make_detector("cnn", backend="int8")``) to a factory that takes them. The oracle is not in the
registry: it needs the true pose and track, so the code that owns the simulator builds it.
"""

from __future__ import annotations

import importlib
import inspect
from collections.abc import Callable

from icarus_vision.gate_detect.base import Detector

_FACTORIES: dict[str, Callable[..., Detector]] = {}
_BUILT_IN = {
    "opencv": "icarus_vision.gate_detect.opencv_detector",
    "cnn": "icarus_vision.gate_detect.cnn",
}
"""Detector modules imported on first use (importing one registers its factory)."""


def _load_built_in(name: str | None = None) -> None:
    for key, module in _BUILT_IN.items():
        if (name is None or key == name) and key not in _FACTORIES:
            importlib.import_module(module)


def register_detector(name: str, factory: Callable[..., Detector]) -> None:
    """Make ``make_detector(name[:arg], **settings)`` call ``factory(arg, **settings)`` (arg
    None when not given)."""
    _FACTORIES[name] = factory


def available_detectors() -> tuple[str, ...]:
    """Names of the registered image detectors (the built-in ones included)."""
    _load_built_in()
    return tuple(sorted(_FACTORIES))


def parse_spec(spec: str) -> tuple[str, str | None]:
    """``"cnn:PATH"`` -> ("cnn", "PATH"); ``"opencv"`` -> ("opencv", None)."""
    name, _, arg = str(spec).partition(":")
    return name.strip(), (arg or None)


def make_detector(spec: str, **settings) -> Detector:
    """The registered detector named by ``spec`` (``NAME`` or ``NAME:ARG``), built with
    ``settings`` (for the CNN: ``backend``, ``threads``, ...; see its ``load``).

    Raises:
        ValueError: no detector of that name is registered; settings it does not take; a
            corrupt checkpoint.
        FileNotFoundError: a checkpoint path that does not exist.
    """
    name, arg = parse_spec(spec)
    _load_built_in(name)
    if name not in _FACTORIES:
        known = ", ".join((*available_detectors(), "oracle"))
        raise ValueError(f"unknown detector {name!r}; choose one of {known}")
    factory = _FACTORIES[name]
    try:
        inspect.signature(factory).bind(arg, **settings)
    except TypeError:
        raise ValueError(
            f"the {name} detector takes no setting {', '.join(sorted(settings))}"
        ) from None
    return factory(arg, **settings)
