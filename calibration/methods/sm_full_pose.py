"""sm-full-pose (report 7.1): the full pose ``X = [x, y, z, phi]`` is measured.

Residual ``X_M - F(Qm, xi)`` (phi wrapped), observation matrix the generalized
Jacobian itself (``Phi = Psi``). All 13 parameters are identifiable.
"""
from __future__ import annotations


from calibration.methods.base import RobotMethod, channel
from calibration.robots.agebot_sm import wrap


class FullPose(RobotMethod):
    method = "sm-full-pose"
    default_damping = 1e-4

    def __init__(self, robot, qm, measured: dict, nominal):
        super().__init__(robot, qm, nominal)
        self.X_m = channel(measured, "pose", self.method, shape=(4,))
        self._channels(("x", "y", "z", "phi"), [0, 1, 2, 3])

    def evaluate(self, x):
        X, psi = self.robot.fk_jacobian(self.qm, x)
        r = self.X_m - X
        r[:, 3] = wrap(r[:, 3])
        return r.reshape(-1), psi.reshape(-1, self.nr)
