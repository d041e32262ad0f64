"""pm-ik (report 10.1): calibration through the PM's inverse kinematics.

All three Euler angles ``X_M`` are measured (channel ``orientation``) together
with the actuator values ``Qm_M``. Rows per pose, channels ``q1, q2, q3``: the
report's joint-space error (eqs. 107, 110)

    Delta Q = Q_M - Q = (K Qm_M + Q_off) - Fbar^-1(X_M, a1, a2, l, v)   [m]

with observation matrix ``Psi^IKU(X_M, xi)`` (eq. 106) exactly: no FK and no
approximation of eq. 111 (the joint-space form is chosen over the actuator-space
``k (Qm_M - Qm)`` because it is exactly linear in the offsets and gear ratios).
The orientation noise enters through ``dq/dX``; the solver's per-channel sigma
weights each actuator's row. ``q3_off, k3`` are not identifiable and are fully
compensated (eqs. 112-113), N_R = 8.
"""
from __future__ import annotations

import numpy as np

from calibration.errors import CalibrationError
from calibration.methods.pm_common import COMPONENTS, STARTS, PMMethod, orientation_channel
from calibration.pm_start import feasible_start


class InverseKinematics(PMMethod):
    method = "pm-ik"

    def __init__(self, robot, qm, measured: dict, nominal, *, start: str = "robust"):
        super().__init__(robot, qm, nominal)
        if start not in STARTS:
            raise CalibrationError(f"start must be one of {STARTS}, not {start!r}")
        self.X_m = orientation_channel(measured, COMPONENTS, self.method)
        if start == "robust":  # move l until the IK reaches every measured orientation
            self.x0 = feasible_start(robot, self.qm, self.X_m, self.nominal)
        self._channels(("q1", "q2", "q3"), [0, 1, 2])

    def evaluate(self, x):
        q, _ = self.robot.ik_joints(self.X_m, x)  # UnreachablePose where a rod cannot reach
        r = self.robot.joints(self.qm, x) - q
        W = self.robot.psi_iku(self.X_m, x, self.qm)
        return r.reshape(-1), W.reshape(-1, self.nr)

    def residual_noise_gain(self, x):
        """Joint-space residual per radian of orientation noise (row norm of dq/dX)."""
        return np.linalg.norm(self.robot.ik_x_jacobian(self.X_m, x), axis=2).reshape(-1)
