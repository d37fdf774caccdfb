"""Point-mass lower bound against the analytic thrust-limited bang-bang time."""

from __future__ import annotations

import math

import pytest

from icarus_vision.planning import bang_bang_time
from icarus_vision.planning.geometry import build_layout
from icarus_vision.planning.point_mass import solve_point_mass
from icarus_vision.sim.quad import GRAVITY, QuadParams

from .conftest import STRAIGHT_DISTANCE


def test_bang_bang_formula():
    q = QuadParams(thrust_to_weight=2.0)
    a_h = math.sqrt((2.0 * GRAVITY) ** 2 - GRAVITY**2)
    assert bang_bang_time(8.0, q) == pytest.approx(math.sqrt(16.0 / a_h))


@pytest.mark.parametrize("twr", [2.0, 4.0])
def test_point_mass_matches_analytic_without_drag(straight_track, twr):
    """Drag-free: the point mass is the classic thrust-limited one; window shrunk to ±1 cm."""
    q = QuadParams(drag=(0.0, 0.0, 0.0), thrust_to_weight=twr)
    layout = build_layout(straight_track, q, nodes_per_gate=10, tol=0.49)
    pm = solve_point_mass(layout, q)
    assert pm.status == "Solve_Succeeded"
    assert pm.total_time == pytest.approx(bang_bang_time(STRAIGHT_DISTANCE, q), rel=0.01)


def test_point_mass_with_drag_is_not_faster_than_drag_free(straight_track, quad):
    layout = build_layout(straight_track, quad, nodes_per_gate=10, tol=0.49)
    pm = solve_point_mass(layout, quad)
    analytic = bang_bang_time(STRAIGHT_DISTANCE, quad)
    assert analytic * (1 - 1e-3) <= pm.total_time <= analytic * 1.05
