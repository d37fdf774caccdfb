"""Shared planning fixtures: small tracks and their plans, solved once per session."""

from __future__ import annotations

import pytest

from icarus_vision.planning import plan
from icarus_vision.sim.builtin import builtin_track
from icarus_vision.sim.quad import QuadParams
from icarus_vision.sim.track import Gate, Track

STRAIGHT_DISTANCE = 5.0


@pytest.fixture(scope="session")
def quad() -> QuadParams:
    return QuadParams()


@pytest.fixture(scope="session")
def straight_track() -> Track:
    """One gate straight ahead at the start's height (2 m, clear of the ground)."""
    return Track(
        name="straight",
        gates=(Gate(pos=(STRAIGHT_DISTANCE, 0.0, 2.0)),),
        start_pos=(0.0, 0.0, 2.0),
    )


@pytest.fixture(scope="session")
def three_gates() -> Track:
    return builtin_track("three-gates")


@pytest.fixture(scope="session")
def straight_plan(straight_track, quad):
    return plan(straight_track, quad, nodes_per_gate=20, cache_dir=None)


@pytest.fixture(scope="session")
def three_gates_plan(three_gates, quad):
    return plan(three_gates, quad, nodes_per_gate=12, cache_dir=None)
