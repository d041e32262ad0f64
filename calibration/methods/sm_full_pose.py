"""sm-full-pose (report 7.1): the full pose of the tool is measured.

AGEBOT: ``X = [x, y, z, phi]`` (4 rows). A robot file: ``X = [x, y, z, roll,
pitch, yaw]`` (6 rows, URDF convention ``R = Rz(yaw) Ry(pitch) Rx(roll)``), the
angle rows' observation matrix the rpy rates of the generalized Jacobian's
rotation (singular where ``cos(pitch) = 0``; the trace generator plans away from it).

Residual ``X_M - F(Qm, xi)`` (angles wrapped), observation matrix ``dF/dxi``
(the generalized Jacobian, ``Phi = Psi``). All AGEBOT's 13 parameters are
identifiable; a general serial robot's ``4 n_R + 2 n_P + 6`` geometric ones
and its transmission ratios are (eq. 8).
"""
from __future__ import annotations


from calibration.methods.base import RobotMethod, channel
from calibration.robots.agebot_sm import wrap


class FullPose(RobotMethod):
    method = "sm-full-pose"
    default_damping = 1e-4

    def __init__(self, robot, qm, measured: dict, nominal):
        super().__init__(robot, qm, nominal)
        n = len(robot.coords)
        self.X_m = channel(measured, "pose", self.method, shape=(n,))
        self.angles = list(robot.angle_coords)
        self._channels(robot.coords, list(range(n)))

    def evaluate(self, x):
        X, psi = self.robot.fk_jacobian(self.qm, x)
        r = self.X_m - X
        r[:, self.angles] = wrap(r[:, self.angles])
        return r.reshape(-1), psi.reshape(-1, self.nr)
