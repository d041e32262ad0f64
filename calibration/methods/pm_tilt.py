"""pm-tilt: pm-fk with a physical dual-axis inclinometer on the platform.

The sensor reads the direction of gravity in its own frame (roll, pitch of
:func:`calibration.robots.agebot_pm.gravity_tilt`), not Euler angles, and sits
on the platform with a small unknown rotation ``R_mount = Rx(mount_x) Ry(mount_y)``.
Trace channel ``tilt`` ``(m, 2)`` = (roll, pitch), rad; model channels ``roll``,
``pitch``. Parameters: the robot's 10, then ``mount_x, mount_y``.

Rows per pose: ``tilt_M - gravity_tilt(R(F(Qm, xi)), mount)`` (wrapped); observation
matrix ``dT/dX Psi^PKU`` for xi and ``dT/dmount`` for the mount
(:func:`calibration.robots.agebot_pm.tilt_jacobian`). A rotation about the
vertical is invisible to the sensor (yaw is lost, two rows per pose); with it,
``q3_off, k3`` stay compensated (eqs. 112-113) as in pm-fk.
"""
from __future__ import annotations

import numpy as np

from calibration.errors import CalibrationError
from calibration.methods import MethodData
from calibration.methods.base import channel
from calibration.methods.pm_common import STARTS, ModeKeepingFK, PMMethod, wrap
from calibration.pm_start import guess_orientations, robust_start_detail
from calibration.robots.agebot_pm import tilt_jacobian


class Tilt(PMMethod):
    method = "pm-tilt"
    extra_names = ("mount_x", "mount_y")

    def __init__(self, robot, qm, measured: dict, nominal, *, start: str = "robust",
                 start_options=None):
        super().__init__(robot, qm, nominal)
        if start not in STARTS:
            raise CalibrationError(f"start must be one of {STARTS}, not {start!r}")
        self.T_m = channel(measured, "tilt", self.method, shape=(2,))
        self.start = None
        if start == "robust":
            data = MethodData(self.qm, {"tilt": self.T_m})
            self.start = robust_start_detail(robot, data, self.nominal, options=start_options)
            self.x0, guess = self.start.x.copy(), self.start.X
        else:
            guess = guess_orientations(self.T_m, None)
        self.fk = ModeKeepingFK(robot, self.qm, guess)
        self._channels(("roll", "pitch"), [0, 1])
        self.noise_groups = (self.channels,)  # one inclinometer's two axes

    def evaluate(self, x):
        xi, mount = x[:self.nr], x[self.nr:]
        X = self.fk(xi)
        t, dT_dX, dT_dm = tilt_jacobian(X, mount)
        r = wrap(self.T_m - t)
        W = np.concatenate([dT_dX @ self.robot.psi_pku(X, xi, self.qm), dT_dm], axis=2)
        return r.reshape(-1), W.reshape(-1, len(self.names))
