"""The PyBullet backend: the drone is a rigid body moved by applied forces and torques.

PyBullet (DIRECT mode, one client per env) integrates the rigid body and reports contacts; the
thrust, drag and rate-controller torque come from ``dynamics.body_wrench`` and the rules from
``RaceCore``, exactly as in the numpy backend. This is the world the FPV camera renders from.
"""

from __future__ import annotations

import numpy as np

from icarus_vision.sim import dynamics
from icarus_vision.sim.bullet import p
from icarus_vision.sim.dynamics import QuadState
from icarus_vision.sim.env import DroneRacingEnv
from icarus_vision.sim.quad import GRAVITY
from icarus_vision.sim.track import Track

GATE_RGBA = (0.95, 0.35, 0.05, 1.0)
GROUND_RGBA = (0.35, 0.45, 0.3, 1.0)
CONTACT_TOL = 1e-3  # m: Bullet reports near-contacts; only touching (distance <= 1 mm) counts


def gate_bar_boxes(size: float, frame_width: float) -> list[tuple[tuple, tuple]]:
    """The four bars of a gate as boxes in the gate frame.

    Returns:
        [(half_extents (3,), centre (3,))] for top, bottom, left, right bars; top and bottom span
        the full outer width. Matches ``rules.bar_distance_local``.
    """
    h, w = size / 2.0, frame_width
    hw = w / 2.0
    return [
        ((hw, h + w, hw), (0.0, 0.0, h + hw)),
        ((hw, h + w, hw), (0.0, 0.0, -(h + hw))),
        ((hw, hw, h), (0.0, h + hw, 0.0)),
        ((hw, hw, h), (0.0, -(h + hw), 0.0)),
    ]


def build_gate(
    client: int, pos, yaw: float, size: float, frame_width: float, rgba=GATE_RGBA
) -> int:
    """Create one static gate body (four box bars, collision + visual) and return its id."""
    boxes = gate_bar_boxes(size, frame_width)
    halves = [list(b[0]) for b in boxes]
    centres = [list(b[1]) for b in boxes]
    col = p.createCollisionShapeArray(
        [p.GEOM_BOX] * 4,
        halfExtents=halves,
        collisionFramePositions=centres,
        physicsClientId=client,
    )
    vis = p.createVisualShapeArray(
        [p.GEOM_BOX] * 4,
        halfExtents=halves,
        visualFramePositions=centres,
        rgbaColors=[list(rgba)] * 4,
        physicsClientId=client,
    )
    orn = p.getQuaternionFromEuler((0.0, 0.0, yaw))
    return p.createMultiBody(0.0, col, vis, list(pos), orn, physicsClientId=client)


def build_world(client: int, track: Track) -> tuple[int, list[int]]:
    """Ground plane and one body per physical gate (a gate flown twice is built once).

    Returns:
        ground body id, gate body ids.
    """
    plane = p.createCollisionShape(p.GEOM_PLANE, physicsClientId=client)
    # Bullet has no visual for planes: a large thin box just below z = 0 shows the ground.
    plane_vis = p.createVisualShape(
        p.GEOM_BOX, halfExtents=[200, 200, 0.01], visualFramePosition=[0, 0, -0.01],
        rgbaColor=list(GROUND_RGBA), physicsClientId=client,
    )  # fmt: skip
    ground = p.createMultiBody(0.0, plane, plane_vis, [0, 0, 0], physicsClientId=client)
    gates = [
        build_gate(client, g.pos, g.yaw, g.size, g.frame_width) for g in track.physical_gates()
    ]
    return ground, gates


class PyBulletDroneRacingEnv(DroneRacingEnv):
    """One drone in its own PyBullet DIRECT client."""

    backend_name = "pybullet"

    def __init__(self, config=None, **overrides) -> None:
        super().__init__(config, **overrides)
        self.client = p.connect(p.DIRECT)
        self._world_track: Track | None = None
        self.drone = -1
        self.ground = -1
        self.gate_ids: list[int] = []

    def _build(self, track: Track) -> None:
        c = self.client
        p.resetSimulation(physicsClientId=c)
        p.setGravity(0, 0, -GRAVITY, physicsClientId=c)
        p.setTimeStep(1.0 / self.config.physics_hz, physicsClientId=c)
        p.setPhysicsEngineParameter(numSubSteps=0, physicsClientId=c)
        self.ground, self.gate_ids = build_world(c, track)
        quad = self.config.quad
        sphere = p.createCollisionShape(p.GEOM_SPHERE, radius=quad.radius, physicsClientId=c)
        vis = p.createVisualShape(
            p.GEOM_SPHERE, radius=quad.radius, rgbaColor=[0.1, 0.1, 0.1, 1], physicsClientId=c
        )
        self.drone = p.createMultiBody(quad.mass, sphere, vis, [0, 0, 1], physicsClientId=c)
        p.changeDynamics(
            self.drone, -1, localInertiaDiagonal=list(quad.inertia), linearDamping=0.0,
            angularDamping=0.0, restitution=0.0, physicsClientId=c,
        )  # fmt: skip
        self._world_track = track

    def _backend_reset(self, state: QuadState) -> None:
        track = self.core.tracks[0]
        if self._world_track is None or self._world_track != track:
            self._build(track)
        c = self.client
        # Setting the mass makes Bullet recompute the inertia from the sphere: set both together.
        p.changeDynamics(
            self.drone, -1, mass=float(self.core.params.mass[0]),
            localInertiaDiagonal=list(self.config.quad.inertia), physicsClientId=c,
        )  # fmt: skip
        p.resetBasePositionAndOrientation(
            self.drone, state.pos[0].tolist(), state.quat[0].tolist(), physicsClientId=c
        )
        self._rot = dynamics.quat_to_rot(state.quat)
        p.resetBaseVelocity(
            self.drone,
            state.vel[0].tolist(),
            (self._rot[0] @ state.omega[0]).tolist(),
            physicsClientId=c,
        )

    def _read_state(self) -> None:
        c, s = self.client, self.state
        pos, orn = p.getBasePositionAndOrientation(self.drone, physicsClientId=c)
        lin, ang = p.getBaseVelocity(self.drone, physicsClientId=c)
        s.pos[0], s.quat[0], s.vel[0] = pos, orn, lin
        self._rot = dynamics.quat_to_rot(s.quat)
        s.omega[0] = self._rot[0].T @ np.asarray(ang)

    def _backend_step(self, thrust_cmd, rate_cmd, wind):
        c, cfg, params = self.client, self.config, self.core.params
        dt = 1.0 / cfg.physics_hz
        trail = np.empty((cfg.substeps, 1, 3))
        frame_hit = ground_hit = False
        gates = set(self.gate_ids)
        for k in range(cfg.substeps):
            thrust, force, torque = dynamics.body_wrench(
                self.state, thrust_cmd, rate_cmd, wind, params, dt, self._rot
            )
            self.state.thrust[:] = thrust
            p.applyExternalForce(
                self.drone,
                -1,
                force[0].tolist(),
                self.state.pos[0].tolist(),
                p.WORLD_FRAME,
                physicsClientId=c,
            )
            p.applyExternalTorque(
                self.drone, -1, torque[0].tolist(), p.WORLD_FRAME, physicsClientId=c
            )
            p.stepSimulation(physicsClientId=c)
            self._read_state()
            trail[k, 0] = self.state.pos[0]
            for contact in p.getContactPoints(bodyA=self.drone, physicsClientId=c):
                if contact[8] > CONTACT_TOL:
                    continue
                if contact[2] in gates:
                    frame_hit = True
                elif contact[2] == self.ground:
                    ground_hit = True
        return trail, np.array([frame_hit]), np.array([ground_hit])

    def close(self) -> None:
        if self.client >= 0 and p.isConnected(self.client):
            p.disconnect(self.client)
        self.client = -1
