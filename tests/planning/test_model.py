"""The CasADi shooting step reproduces the simulator's dynamics (sim.dynamics.step_substeps)."""

from __future__ import annotations

import numpy as np
import pytest

from icarus_vision.planning.model import step_function
from icarus_vision.sim.dynamics import QuadBatchParams, QuadState, rpy_to_quat, step_substeps


@pytest.mark.parametrize(("h", "substeps"), [(0.01, 1), (0.03, 1), (0.09, 3)])
def test_step_matches_simulator(quad, h, substeps):
    """Random (aggressive) states and commands; the planner keeps RK4 sub-steps <= 0.03 s."""
    rng = np.random.default_rng(0)
    n = 8
    state = QuadState(
        pos=rng.uniform(-1, 1, (n, 3)),
        vel=rng.uniform(-10, 10, (n, 3)),
        quat=rpy_to_quat(rng.uniform(-1.5, 1.5, (n, 3))),
        omega=rng.uniform(-5, 5, (n, 3)),
        thrust=rng.uniform(0, quad.thrust_max, n),
    )
    tau_cmd = rng.uniform(0, 1, n)
    rate_cmd = rng.uniform(-1, 1, (n, 3)) * np.array(quad.max_rate)
    x = np.hstack(
        [state.pos, state.vel, state.quat, state.omega, state.thrust[:, None] / quad.thrust_max]
    )
    u = np.hstack([tau_cmd[:, None], rate_cmd])
    out = np.array(step_function(quad, substeps).map(n)(x.T, u.T, h)).T
    sub = round(h / 2e-5)
    params = QuadBatchParams.from_quad(quad, n)
    step_substeps(
        state, tau_cmd * quad.thrust_max, rate_cmd, np.zeros((n, 3)), params, h / sub, sub
    )
    np.testing.assert_allclose(out[:, 0:3], state.pos, atol=3e-4)
    np.testing.assert_allclose(out[:, 3:6], state.vel, atol=5e-3)
    np.testing.assert_allclose(out[:, 13] * quad.thrust_max, state.thrust, atol=1e-6)
    np.testing.assert_allclose(out[:, 10:13], state.omega, atol=1e-6)
    q = out[:, 6:10] / np.linalg.norm(out[:, 6:10], axis=1, keepdims=True)
    dots = np.abs(np.einsum("ij,ij->i", q, state.quat))
    np.testing.assert_allclose(dots, 1.0, atol=1e-5)
