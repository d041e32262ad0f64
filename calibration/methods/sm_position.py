"""sm-position: the position of the tool origin is measured (a laser tracker's
reflector on the tool), channel ``position = [x, y, z]`` in the base frame, m.

Residual ``p_M - p(Qm, xi)``, observation matrix the position rows of the
generalized Jacobian (eqs. 16-24). The tool's orientation is not seen: of a
general serial robot's ``4 n_R + 2 n_P + 6`` geometric parameters, the three
that only turn the tool about its origin are not identifiable (27 for a 6R arm
with fixed ratios).
"""
from __future__ import annotations

import numpy as np

from calibration.methods.base import RobotMethod, channel


class Position(RobotMethod):
    method = "sm-position"
    default_damping = 1e-4

    def __init__(self, robot, qm, measured: dict, nominal):
        super().__init__(robot, qm, nominal)
        self.p_m = channel(measured, "position", self.method, shape=(3,))
        self._channels(("x", "y", "z"), [0, 1, 2])
        # one point a pose: its 3D error is what an engineer reads (point_errors)
        self.pose_of = np.arange(self.n_poses)
        self.marker_of = np.zeros(self.n_poses, dtype=int)

    def point_errors(self, r):
        """3D distance of each pose's point from its prediction, from the residual ``r``."""
        return np.linalg.norm(np.asarray(r, dtype=float).reshape(-1, 3), axis=1)

    def evaluate(self, x):
        # the chain's position rows only (no orientation rates to compute)
        p, J = self.robot.position_jacobian(self.qm, x)
        return (self.p_m - p).reshape(-1), J.reshape(-1, self.nr)
