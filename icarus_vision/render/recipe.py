"""Visual domain-randomisation recipe: frozen dataclasses of ranges, loaded from TOML.

A recipe file (e.g. ``datasets/gates-v1.toml``) has one table per section dataclass: ``[gates]``,
``[ground]``, ``[sky]``, ``[light]``, ``[distractors]``, ``[camera]``, ``[sensor]``, ``[hall]``, the geometry
of the frames (``[tracks]``, ``[poses]``), the dataset layout (``[dataset]``), plus a top-level
``name``. Missing keys take the defaults; an unknown key or a bad value raises ValueError naming the
key and the file. Ranges are ``[low, high]`` and are sampled uniformly.

This module gathers the public names: the section dataclasses live in
:mod:`icarus_vision.render.recipe_sections`, the TOML loading and validation in
:mod:`icarus_vision.render.recipe_toml`.
"""

from __future__ import annotations

from icarus_vision.render.recipe_sections import (
    CameraJitter,
    DatasetSettings,
    DistractorRanges,
    GateRanges,
    HallRanges,
    LightRanges,
    PoseRanges,
    Range,
    Recipe,
    SensorRanges,
    SurfaceRanges,
    TrackRanges,
)
from icarus_vision.render.recipe_toml import load_recipe, recipe_from_dict

__all__ = [
    "CameraJitter",
    "DatasetSettings",
    "DistractorRanges",
    "GateRanges",
    "HallRanges",
    "LightRanges",
    "PoseRanges",
    "Range",
    "Recipe",
    "SensorRanges",
    "SurfaceRanges",
    "TrackRanges",
    "load_recipe",
    "recipe_from_dict",
]
