"""A third-party physics backend as small as one can be: the numpy model, stepped by this module.

Installed as a distribution beside it (``icarus_tiny_backend-0.1.dist-info``) whose entry point in
the ``icarus_vision.backends`` group names ``TinyDroneRacingEnv``; the tests put this folder on
``sys.path``, which is all an installed package is.
"""

from __future__ import annotations

import numpy as np

from icarus_vision.sim.dynamics import step_substeps
from icarus_vision.sim.env import DroneRacingEnv


class TinyDroneRacingEnv(DroneRacingEnv):
    backend_name = "tiny"

    def _backend_reset(self, state) -> None:
        pass  # no world to build: the drone's state lives in self.state

    def _backend_step(self, thrust_cmd, rate_cmd, wind):
        core, cfg = self.core, self.config
        trail = step_substeps(
            self.state, thrust_cmd, rate_cmd, wind, core.params, 1.0 / cfg.physics_hz,
            cfg.substeps, ground_clamp=~core.taken_off,
        )  # fmt: skip
        frame_hit = core.frame_collision(trail)
        ground_hit = np.min(trail[:, :, 2], axis=0) < core.params.radius
        return trail, frame_hit, ground_hit
