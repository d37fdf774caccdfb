"""The quadrotor model of ``sim.dynamics`` in CasADi, discretised for multiple shooting.

State x (14): position p (3, world, m), velocity v (3, world, m/s), attitude q (4, x y z w, body ->
world), body rates ω (3, rad/s), collective thrust as a fraction of T_max τ (1).
Control u (4): thrust command τ_c ∈ [0, 1] (fraction of T_max) and body-rate commands ω_c (3, rad/s)
within ±max_rate, held constant over each shooting interval.

The rate and thrust lag is modelled, as in the simulator: ω and τ follow their commands with the
first-order time constant ``motor_tau``. Keeping it costs only four states, makes the optimal time
the one the simulated drone can actually fly (a policy commands rates, it does not set them), and lets
a planned command sequence be replayed in the simulator. Because the commands are constant on an
interval, the lag states are integrated *exactly* (exponential form), so the 30 ms time constant
does not make the integrator stiff; p, v and q use classic RK4 with ω(t) and τ(t) evaluated in
closed form at the stage times.

Forces (as in ``sim.dynamics.step_substeps``, no wind): thrust τ T_max along body z, body-frame
linear drag −R diag(drag) Rᵀ v, gravity (0, 0, −g).
"""

from __future__ import annotations

import casadi as ca

from icarus_vision.sim.quad import GRAVITY, QuadParams

NX = 14
NU = 4


def rotation(q):
    """Body -> world rotation matrix (3, 3) of a quaternion x, y, z, w (CasADi).

    Written in the homogeneous form divided by |q|², so it is the exact rotation of q / |q| also at
    the solver's intermediate iterates and inside RK4 stages, where q is not exactly unit.
    """
    x, y, z, w = q[0], q[1], q[2], q[3]
    xx, yy, zz, ww = x * x, y * y, z * z, w * w
    r = ca.vertcat(
        ca.horzcat(ww + xx - yy - zz, 2 * (x * y - w * z), 2 * (x * z + w * y)),
        ca.horzcat(2 * (x * y + w * z), ww - xx + yy - zz, 2 * (y * z - w * x)),
        ca.horzcat(2 * (x * z - w * y), 2 * (y * z + w * x), ww - xx - yy + zz),
    )
    return r / (xx + yy + zz + ww)


def quat_rate(q, omega):
    """dq/dt = ½ q ⊗ (ω, 0) for body rates ω (matches ``sim.dynamics.quat_integrate``)."""
    x, y, z, w = q[0], q[1], q[2], q[3]
    wx, wy, wz = omega[0], omega[1], omega[2]
    return 0.5 * ca.vertcat(
        w * wx + y * wz - z * wy,
        w * wy + z * wx - x * wz,
        w * wz + x * wy - y * wx,
        -(x * wx + y * wy + z * wz),
    )


def accel(q, v, tau, quad: QuadParams):
    """World acceleration (3,) for attitude q, velocity v and thrust fraction tau."""
    r = rotation(q)
    drag = ca.DM(list(quad.drag))
    body_v = r.T @ v
    force = r[:, 2] * (tau * quad.thrust_max) - r @ (drag * body_v)
    return force / quad.mass + ca.DM([0.0, 0.0, -GRAVITY])


def step_function(quad: QuadParams, substeps: int = 1) -> ca.Function:
    """CasADi function ``F(x, u, h) -> x_next`` advancing the state over one interval of length h.

    Args:
        quad: mass, thrust, drag and lag time constant.
        substeps: RK4 sub-steps per interval for p, v, q (the lag states are exact).
    """
    x = ca.SX.sym("x", NX)
    u = ca.SX.sym("u", NU)
    h = ca.SX.sym("h")
    tau_m = quad.motor_tau
    om0, tau0 = x[10:13], x[13]
    tau_c, om_c = u[0], u[1:4]

    def lagged(t):
        decay = ca.exp(-t / tau_m)
        return om_c + (om0 - om_c) * decay, tau_c + (tau0 - tau_c) * decay

    def f(p, v, q, t):
        om, tau = lagged(t)
        return v, accel(q, v, tau, quad), quat_rate(q, om)

    p, v, q = x[0:3], x[3:6], x[6:10]
    dt = h / substeps
    for s in range(substeps):
        t0 = s * dt
        k1 = f(p, v, q, t0)
        k2 = f(*(a + 0.5 * dt * k for a, k in zip((p, v, q), k1, strict=True)), t0 + 0.5 * dt)
        k3 = f(*(a + 0.5 * dt * k for a, k in zip((p, v, q), k2, strict=True)), t0 + 0.5 * dt)
        k4 = f(*(a + dt * k for a, k in zip((p, v, q), k3, strict=True)), t0 + dt)
        p, v, q = (
            a + dt / 6.0 * (b1 + 2 * b2 + 2 * b3 + b4)
            for a, b1, b2, b3, b4 in zip((p, v, q), k1, k2, k3, k4, strict=True)
        )
    om_end, tau_end = lagged(h)
    q = q / ca.sqrt(ca.sumsqr(q))  # every node's attitude is then a unit quaternion
    return ca.Function("quad_step", [x, u, h], [ca.vertcat(p, v, q, om_end, tau_end)])
