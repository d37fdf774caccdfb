"""A scripted (non-learning) racing controller: geometric position control mapped to CTBR actions.

It follows the line through each gate along the gate's passage direction: the set-point ("carrot")
is the point of that line ``lookahead`` metres beyond the drone's projection on it, so the drone
lines up with the gate axis before the plane and flies straight through the opening. A velocity
loop gives the desired acceleration; the thrust vector fixes the desired body z axis and collective
thrust; an attitude loop on SO(3) (Lee et al., 2010) turns the attitude error into body-rate
commands. Everything is batched over N drones and reads only the 15-D observation plus the next
gate's heading, so it flies on either backend. It is the baseline the learned policy must beat.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from icarus_vision.sim.dynamics import cross, quat_to_rot, rpy_to_quat
from icarus_vision.sim.quad import GRAVITY, QuadParams


@dataclass(frozen=True)
class ScriptedGains:
    """Gains and limits of the scripted controller."""

    cruise_speed: float = 5.0
    """Speed along the path, m/s."""
    lookahead: float = 1.5
    """Carrot distance ahead of the drone's projection on the gate axis, m."""
    k_pos: float = 2.0
    """Carrot distance to speed, 1/s (the speed is min(cruise_speed, k_pos · distance))."""
    approach_slope: float = 1.0
    """Off-axis drones aim at least this many metres in front of the gate per metre of offset."""
    overshoot: float = 2.0
    """How far past the gate plane the carrot may go, m."""
    k_vel: float = 4.0
    """Velocity error to acceleration, 1/s."""
    max_acc: float = 15.0
    """Horizontal acceleration limit, m/s²."""
    k_att: float = 8.0
    """Attitude error to body rate, 1/s."""
    k_yaw: float = 2.0
    """Yaw error to yaw rate, 1/s."""
    max_yaw_step: float = 1.0
    """Largest heading error handed to the attitude loop, rad."""


class ScriptedController:
    """Batched geometric controller producing ``[thrust, roll_rate, pitch_rate, yaw_rate]`` actions."""

    def __init__(self, quad: QuadParams | None = None, gains: ScriptedGains | None = None) -> None:
        self.quad = quad or QuadParams()
        self.gains = gains or ScriptedGains()

    def act(self, obs: np.ndarray, gate_yaw: np.ndarray) -> np.ndarray:
        """Actions for N drones.

        Args:
            obs: (N, 15) observations with the gate vector obs[:, 12:15] in the world frame.
            gate_yaw: (N,) heading of each drone's next gate, radians.

        Returns:
            (N, 4) float32 actions in [-1, 1].
        """
        g, q = self.gains, self.quad
        obs = np.atleast_2d(np.asarray(obs, dtype=np.float64))
        gate_yaw = np.atleast_1d(np.asarray(gate_yaw, dtype=np.float64))
        pos, vel, rpy = obs[:, 0:3], obs[:, 3:6], obs[:, 6:9]
        gate = pos + obs[:, 12:15]
        normal = np.stack((np.cos(gate_yaw), np.sin(gate_yaw), np.zeros_like(gate_yaw)), axis=1)

        # Carrot on the gate axis, ahead of the drone's projection on it.
        along = np.einsum("ij,ij->i", pos - gate, normal)
        offset = np.linalg.norm(pos - gate - along[:, None] * normal, axis=1)
        # Far off the axis, keep the carrot on the entry side so the approach clears the frame.
        s = np.minimum(
            np.minimum(along + g.lookahead, g.overshoot), -g.approach_slope * (offset - 0.3)
        )
        carrot = gate + normal * s[:, None]
        to_carrot = carrot - pos
        dist = np.linalg.norm(to_carrot, axis=1, keepdims=True)
        v_des = to_carrot / np.maximum(dist, 1e-6) * np.minimum(g.cruise_speed, g.k_pos * dist)
        acc = g.k_vel * (v_des - vel)
        horiz = np.linalg.norm(acc[:, :2], axis=1, keepdims=True)
        acc[:, :2] *= np.minimum(1.0, g.max_acc / np.maximum(horiz, 1e-6))
        acc[:, 2] = np.clip(acc[:, 2], -0.7 * GRAVITY, 2.0 * GRAVITY)

        # Thrust vector: compensate gravity and the body drag on the current velocity.
        drag = np.array(q.drag).mean() * vel / q.mass
        f = acc + drag + np.array([0.0, 0.0, GRAVITY])
        rot = quat_to_rot(rpy_to_quat(rpy))
        z_des = f / np.linalg.norm(f, axis=1, keepdims=True)
        thrust = q.mass * np.einsum("ij,ij->i", f, rot[:, :, 2])

        # Desired attitude: body z along the thrust vector, heading turning toward the gate's
        # direction by at most max_yaw_step per call (a 180° heading error would be a singular
        # attitude error on SO(3)).
        yaw_err = np.angle(np.exp(1j * (gate_yaw - rpy[:, 2])))
        heading = rpy[:, 2] + np.clip(yaw_err, -g.max_yaw_step, g.max_yaw_step)
        x_c = np.stack((np.cos(heading), np.sin(heading), np.zeros_like(heading)), axis=1)
        y_des = cross(z_des, x_c)
        y_des /= np.maximum(np.linalg.norm(y_des, axis=1, keepdims=True), 1e-6)
        x_des = cross(y_des, z_des)
        r_des = np.stack((x_des, y_des, z_des), axis=2)
        e = np.einsum("nji,njk->nik", r_des, rot) - np.einsum("nji,njk->nik", rot, r_des)
        e_r = 0.5 * np.stack((e[:, 2, 1], e[:, 0, 2], e[:, 1, 0]), axis=1)
        rates = -np.array([g.k_att, g.k_att, g.k_yaw]) * e_r

        action = np.empty((obs.shape[0], 4))
        action[:, 0] = 2.0 * thrust / q.thrust_max - 1.0
        action[:, 1:] = rates / np.array(q.max_rate)
        return np.clip(action, -1.0, 1.0).astype(np.float32)

    def act_env(self, env, obs: np.ndarray) -> np.ndarray:
        """Actions for a DroneRacingEnv or BatchedRacingVecEnv (reads each drone's next-gate heading)."""
        _, yaw, _ = (
            env.unwrapped.core.target_gate()
            if hasattr(env, "unwrapped")
            else env.core.target_gate()
        )
        return self.act(obs, yaw)


def fly(
    env,
    controller: ScriptedController | None = None,
    seed: int | None = None,
    max_steps: int = 100_000,
) -> dict:
    """Fly one episode of a single-drone env with the scripted controller.

    Returns:
        The final info dict plus ``steps``, ``positions`` (T, 3) and ``speeds`` (T,).
    """
    controller = controller or ScriptedController(env.unwrapped.config.quad)
    obs, info = env.reset(seed=seed)
    positions, speeds = [obs[:3].copy()], [0.0]
    for step in range(max_steps):  # noqa: B007 (step is used after the loop)
        obs, _, term, trunc, info = env.step(controller.act_env(env, obs[None])[0])
        positions.append(obs[:3].copy())
        speeds.append(float(np.linalg.norm(obs[3:6])))
        if term or trunc:
            break
    return {**info, "steps": step + 1, "positions": np.array(positions), "speeds": np.array(speeds)}
