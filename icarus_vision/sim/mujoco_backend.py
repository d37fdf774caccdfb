"""The MuJoCo backend: the same race flown by another physics engine.

The quadrotor is a free MuJoCo body built from the quadrotor file (mass, diagonal inertia, the
collision sphere). Its controls are MuJoCo actuators at the centre of mass:

* collective thrust along body z, a first-order filter actuator with the file's ``motor_tau``
  (``dyntype="filterexact"``, ``actearly``), limited to [0, T_max];
* the body-rate controller, one proportional actuator per body axis, τ = g (ω_c − ω), its gain
  chosen so that the closed loop, as MuJoCo integrates it, is the file's first-order rate lag
  (``rate_gain``; the continuous-time gain J/τ_m would lag about half a step more, and cost the
  generalist 3 points of finish rate); commands limited to ± ``max_rate``.

Drag on the airspeed v − v_wind (linear, diagonal in the body frame), the wind and the controller's
gyroscopic feed-forward ω × Jω are applied forces (``xfrc_applied``). MuJoCo integrates with its
own ``implicit`` integrator at ``physics_hz`` (``implicitfast``, which drops the Coriolis
derivatives, let the body rates run away at the rates racing policies fly: 5 % of random race
layouts finished instead of 75 %), resolves contacts with its soft-contact solver, and its
contacts with the gate and ground geoms decide crashes. The rules, reward and observation
stay ``RaceCore``'s; the camera renders through the PyBullet scene from the drone's pose.

What differs from the numpy model (this backend exists to measure that gap): MuJoCo integrates a
rigid body with its Coriolis terms, which the controller's feed-forward cancels only up to the
step (the numpy model commands the rate directly), in its own integrator, and its contacts push
the drone as well as ending the episode.
"""

from __future__ import annotations

import mujoco
import numpy as np

from icarus_vision.sim.dynamics import QuadState, drag_force, gyro_torque, lag_gain
from icarus_vision.sim.env import DroneRacingEnv
from icarus_vision.sim.pybullet_backend import CONTACT_TOL, GATE_RGBA, GROUND_RGBA, gate_bar_boxes
from icarus_vision.sim.quad import GRAVITY, QuadParams
from icarus_vision.sim.track import Track

INTEGRATOR = "implicit"
_WXYZ, _XYZW = [3, 0, 1, 2], [4, 5, 6, 3]


def rate_gain(inertia: np.ndarray, tau: float, dt: float) -> np.ndarray:
    """Gain (3,) of the proportional rate loop τ = g (ω_c − ω) whose response, as MuJoCo's implicit
    integrator steps it, is the first-order lag ``tau``: each step closes the same fraction
    k = 1 − exp(−dt/τ) of the error as the exact lag (g = J k / (dt (1 − k)); J/τ as dt → 0)."""
    k = lag_gain(dt, tau)
    return np.asarray(inertia, float) * k / (dt * (1.0 - k))


def _vec(v) -> str:
    return " ".join(f"{float(x):.9g}" for x in v)


def model_xml(track: Track, quad: QuadParams, physics_hz: float) -> str:
    """The MJCF of one race: ground, one static body per physical gate, the drone and its actuators.

    Args:
        track: gates (a gate flown twice is built once).
        quad: mass, inertia, radius, motor lag and rate limits.
        physics_hz: MuJoCo's time step is 1 / physics_hz.

    Returns:
        An MJCF string (``mujoco.MjModel.from_xml_string`` compiles it).
    """
    gates = []
    for i, g in enumerate(track.physical_gates()):
        bars = "".join(
            f'<geom name="gate{i}_bar{k}" type="box" size="{_vec(half)}" pos="{_vec(centre)}" '
            f'rgba="{_vec(GATE_RGBA)}"/>'
            for k, (half, centre) in enumerate(gate_bar_boxes(g.size, g.frame_width))
        )
        gates.append(
            f'<body name="gate{i}" pos="{_vec(g.pos)}" euler="0 0 {g.yaw:.9g}">{bars}</body>'
        )
    j = np.asarray(quad.inertia, float)
    kv = rate_gain(j, quad.motor_tau, 1.0 / physics_hz)
    rates = "".join(
        f'<general name="rate_{axis}" site="com" gear="0 0 0 {_vec(np.eye(3)[k])}" '
        f'gainprm="{kv[k]:.9g}" biastype="affine" biasprm="0 0 {-kv[k]:.9g}" '
        f'ctrllimited="true" ctrlrange="{-quad.max_rate[k]:.9g} {quad.max_rate[k]:.9g}"/>'
        for k, axis in enumerate("xyz")
    )
    return f"""<mujoco model="icarus-race">
  <compiler angle="radian"/>
  <option timestep="{1.0 / physics_hz:.9g}" integrator="{INTEGRATOR}" gravity="0 0 {-GRAVITY:.9g}"/>
  <worldbody>
    <geom name="ground" type="plane" size="0 0 1" rgba="{_vec(GROUND_RGBA)}"/>
    {"".join(gates)}
    <body name="drone" pos="0 0 1">
      <freejoint name="drone"/>
      <inertial pos="0 0 0" mass="{quad.mass:.9g}" diaginertia="{_vec(j)}"/>
      <geom name="drone" type="sphere" size="{quad.radius:.9g}" rgba="0.1 0.1 0.1 1"/>
      <site name="com"/>
    </body>
  </worldbody>
  <actuator>
    <general name="thrust" site="com" gear="0 0 1 0 0 0" dyntype="filterexact"
      dynprm="{quad.motor_tau:.9g}" actearly="true" ctrllimited="true"
      ctrlrange="0 {quad.thrust_max:.9g}"/>
    {rates}
  </actuator>
</mujoco>"""


class MuJoCoDroneRacingEnv(DroneRacingEnv):
    """One drone in its own MuJoCo model, rebuilt whenever the episode's track changes."""

    backend_name = "mujoco"

    def __init__(self, config=None, **overrides) -> None:
        super().__init__(config, **overrides)
        self.model: mujoco.MjModel | None = None
        self.data: mujoco.MjData | None = None
        self._world_track: Track | None = None
        self._rot = np.eye(3)

    def _build(self, track: Track) -> None:
        self.model = mujoco.MjModel.from_xml_string(
            model_xml(track, self.config.quad, self.config.physics_hz)
        )
        self.data = mujoco.MjData(self.model)
        m = self.model
        self._body = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "drone")
        self._geom = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, "drone")
        self._ground = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, "ground")
        self._world_track = track

    def _backend_reset(self, state: QuadState) -> None:
        track = self.core.tracks[0]
        if self.model is None or self._world_track != track:
            self._build(track)
        m, d, params = self.model, self.data, self.core.params
        # randomised per episode: mass (the inertia stays the file's), thrust, the lag of the
        # thrust and of the rate loop
        m.body_mass[self._body] = params.mass[0]
        m.actuator_ctrlrange[0, 1] = params.thrust_max[0]
        m.actuator_dynprm[0, 0] = params.motor_tau[0]
        kv = rate_gain(params.inertia, params.motor_tau[0], m.opt.timestep)
        m.actuator_gainprm[1:4, 0], m.actuator_biasprm[1:4, 2] = kv, -kv
        # MuJoCo's constants derived from the mass (without this it integrates the file's mass)
        mujoco.mj_setConst(m, d)
        mujoco.mj_resetData(m, d)
        d.qpos[:3] = state.pos[0]
        d.qpos[3:7] = state.quat[0, _WXYZ]  # MuJoCo's quaternions are w, x, y, z
        d.qvel[:3] = state.vel[0]
        d.qvel[3:6] = state.omega[0]  # a free joint's angular velocity is in the body frame
        d.act[0] = state.thrust[0]
        mujoco.mj_forward(m, d)
        self._read_state()

    def _read_state(self) -> None:
        d, s = self.data, self.state
        s.pos[0] = d.qpos[:3]
        s.quat[0] = d.qpos[_XYZW]
        s.vel[0] = d.qvel[:3]
        s.omega[0] = d.qvel[3:6]
        s.thrust[0] = d.act[0]
        mujoco.mju_quat2Mat(self._rot.reshape(9), d.qpos[3:7])

    def _backend_step(self, thrust_cmd, rate_cmd, wind):
        m, d, params = self.model, self.data, self.core.params
        d.ctrl[0] = thrust_cmd[0]
        d.ctrl[1:4] = rate_cmd[0]
        trail = np.empty((self.config.substeps, 1, 3))
        frame_hit = ground_hit = False
        drag, air, j = params.drag[:1], wind[:1], params.inertia
        wrench = d.xfrc_applied[self._body]
        rot = self._rot[None]  # a view: _read_state updates it in place
        for k in range(self.config.substeps):
            wrench[:3] = drag_force(rot, d.qvel[None, :3], air, drag)[0]
            # the rate controller's gyroscopic feed-forward
            wrench[3:] = self._rot @ gyro_torque(j, d.qvel[None, 3:6])[0]
            mujoco.mj_step(m, d)
            self._read_state()
            trail[k, 0] = d.qpos[:3]
            if d.ncon:
                hit, ground = self._contacts()
                frame_hit |= hit
                ground_hit |= ground
        return trail, np.array([frame_hit]), np.array([ground_hit])

    def _contacts(self) -> tuple[bool, bool]:
        """(touches a gate, touches the ground) among the current contacts of the drone."""
        con = self.data.contact
        pairs = con.geom[con.dist <= CONTACT_TOL]
        others = pairs[(pairs == self._geom).any(axis=1)].sum(axis=1) - self._geom
        ground = bool((others == self._ground).any())
        return bool((others != self._ground).any()), ground

    def close(self) -> None:
        self.model = self.data = None


__all__ = ["MuJoCoDroneRacingEnv", "model_xml", "INTEGRATOR"]
