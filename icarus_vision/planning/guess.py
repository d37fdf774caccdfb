"""Initial guess of the full-model problem from a point-mass solution.

The point mass gives positions, velocities and accelerations on the same node layout. Thrust points
along the required specific force (acceleration − gravity + drag compensation); the attitude is the
one whose body z axis is that direction with the heading held at the start yaw; body rates follow
from consecutive attitudes and are clipped to the limits. The guess solved with derated thrust and a
smoothness penalty (see ``planner``) is dynamically close to feasible, which is what makes IPOPT
converge reliably from it.
"""

from __future__ import annotations

import numpy as np

from icarus_vision.planning.geometry import Layout
from icarus_vision.planning.model import NU, NX
from icarus_vision.planning.point_mass import G_VEC, PointMassSolution
from icarus_vision.sim.quad import GRAVITY, QuadParams


def rot_to_quat(r: np.ndarray) -> np.ndarray:
    """(N, 3, 3) rotation matrices -> (N, 4) unit quaternions x, y, z, w (Shepperd's method)."""
    out = np.empty((len(r), 4))
    for i, m in enumerate(r):
        tr = np.trace(m)
        if tr > 0:
            s = 2.0 * np.sqrt(tr + 1.0)
            out[i] = [
                (m[2, 1] - m[1, 2]) / s,
                (m[0, 2] - m[2, 0]) / s,
                (m[1, 0] - m[0, 1]) / s,
                s / 4,
            ]
        else:
            j = int(np.argmax(np.diag(m)))
            a, b = (j + 1) % 3, (j + 2) % 3
            s = 2.0 * np.sqrt(1.0 + m[j, j] - m[a, a] - m[b, b])
            q = np.empty(4)
            q[j] = s / 4
            q[a] = (m[a, j] + m[j, a]) / s
            q[b] = (m[b, j] + m[j, b]) / s
            q[3] = (m[b, a] - m[a, b]) / s
            out[i] = q
    return out / np.linalg.norm(out, axis=1, keepdims=True)


def quat_mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product a ⊗ b of x, y, z, w quaternions ((4,) or (N, 4))."""
    ax, ay, az, aw = np.moveaxis(a, -1, 0)
    bx, by, bz, bw = np.moveaxis(b, -1, 0)
    return np.stack(
        (
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
            aw * bw - ax * bx - ay * by - az * bz,
        ),
        axis=-1,
    )


def attitude_from_thrust(z_body: np.ndarray, yaw: float) -> np.ndarray:
    """Attitudes (N, 4) x, y, z, w whose body z axes follow ``z_body`` (N, 3) with no twist.

    The first attitude has heading ``yaw``; each next one is the previous turned by the smallest
    rotation taking its body z to the next direction, so the body yaw rate of the sequence is zero
    (yaw-rate limits are often tight, and heading does not matter for a quadrotor's thrust).
    """
    z = z_body / np.linalg.norm(z_body, axis=1, keepdims=True)
    x_c = np.array([np.cos(yaw), np.sin(yaw), 0.0])
    y0 = np.cross(z[0], x_c)
    if np.linalg.norm(y0) < 1e-6:  # thrust along the heading: any perpendicular will do
        y0 = np.cross(z[0], [0.0, 0.0, 1.0]) if abs(z[0, 2]) < 0.9 else np.cross(z[0], [1.0, 0, 0])
    y0 /= np.linalg.norm(y0)
    q = np.empty((len(z), 4))
    q[0] = rot_to_quat(np.stack([np.cross(y0, z[0]), y0, z[0]], axis=1)[None])[0]
    for k in range(1, len(z)):
        axis = np.cross(z[k - 1], z[k])
        s, c = np.linalg.norm(axis), float(np.dot(z[k - 1], z[k]))
        if s < 1e-9:
            q[k] = q[k - 1]
            continue
        half = 0.5 * np.arctan2(s, c)
        turn = np.concatenate([axis / s * np.sin(half), [np.cos(half)]])
        q[k] = quat_mul(turn, q[k - 1])
        q[k] /= np.linalg.norm(q[k])
    return q


def body_rates(q: np.ndarray, dt: np.ndarray) -> np.ndarray:
    """(K, 3) constant body rates turning q[k] into q[k + 1] over dt[k] (q: (K + 1, 4))."""
    conj = q[:-1] * np.array([-1.0, -1.0, -1.0, 1.0])
    d = quat_mul(conj, q[1:])
    d[d[:, 3] < 0] *= -1
    vec = d[:, :3]
    n = np.linalg.norm(vec, axis=1)
    angle = 2.0 * np.arctan2(n, d[:, 3])
    axis = vec / np.maximum(n, 1e-12)[:, None]
    return axis * (angle / dt)[:, None]


def hover_start(layout: Layout, quad: QuadParams) -> np.ndarray:
    """(14,) state at rest at the start pose, thrust balancing gravity."""
    x0 = np.zeros(NX)
    x0[0:3] = layout.start
    x0[6:10] = attitude_from_thrust(np.array([[0.0, 0.0, 1.0]]), layout.start_yaw)[0]
    x0[13] = quad.mass * GRAVITY / quad.thrust_max
    return x0


def full_guess(
    pm: PointMassSolution, layout: Layout, quad: QuadParams
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Segment times (S,), states (K + 1, 14) and controls (K, 4) from a point-mass trajectory."""
    acc = np.vstack([pm.acc, pm.acc[-1:]])
    drag_comp = np.mean(quad.drag) * pm.vel
    f = quad.mass * (acc - G_VEC) + drag_comp
    f[np.linalg.norm(f, axis=1) < 1e-6] = [0.0, 0.0, quad.mass * GRAVITY]
    quat = attitude_from_thrust(f, layout.start_yaw)
    tau = np.clip(np.linalg.norm(f, axis=1) / quad.thrust_max, 0.0, 1.0)
    dt = np.diff(pm.t)
    rates = np.clip(body_rates(quat, dt), -np.asarray(quad.max_rate), np.asarray(quad.max_rate))
    states = np.zeros((len(pm.t), NX))
    states[:, 0:3] = pm.pos
    states[:, 3:6] = pm.vel
    states[:, 6:10] = quat
    states[1:, 10:13] = rates
    states[:, 13] = tau
    states[0] = hover_start(layout, quad)
    controls = np.zeros((len(dt), NU))
    controls[:, 0] = tau[1:]
    controls[:, 1:] = rates
    return pm.segment_times.copy(), states, controls
