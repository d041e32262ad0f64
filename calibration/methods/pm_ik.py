"""pm-ik (report 10.1): calibration through the PM's inverse kinematics.

All three Euler angles ``X_M`` are measured (channel ``orientation``) together
with the actuator values ``Qm_M``. Rows per pose, channels ``q1, q2, q3``, in
actuator units:

    Qm_M - F^-1(X_M, xi),   F^-1 = diag(K)^-1 (Fbar^-1(X_M, a1, a2, l, v) - Q_off)

with observation matrix ``diag(K)^-1 Psi^IKU(X_M, xi)`` (eq. 106, the ``k_i``
column taken at the predicted ``Qm``). This is the report's eq. 111 without its
factor ``diag(K)``: the report's joint-space error ``K (Qm_M - Qm)`` shrinks
with the overall scale of the model (all lengths, offsets and gear ratios
times s give the same actuators but s times the residual), so a fit in joint
space can lower its cost by shrinking the robot towards s = 0, and k3 looks
identifiable wherever the residual is not zero. In actuator units the scale
and the height shift (v and all offsets together) leave every residual
exactly unchanged: ``q3_off, k3`` are not identifiable at any parameter
values, fully compensated (eqs. 112-113), N_R = 8.
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
        xi = np.asarray(x, dtype=float)
        k = xi[7:10]
        # UnreachablePose (a CalibrationError) where a rod cannot reach: the solver rejects the step
        qm_pred = self.robot.ik_actuators(self.X_m, xi)
        W = self.robot.psi_iku(self.X_m, xi, qm_pred) / k[None, :, None]
        return (self.qm - qm_pred).reshape(-1), W.reshape(-1, self.nr)
