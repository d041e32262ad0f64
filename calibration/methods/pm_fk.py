"""pm-fk (report 10.2): calibration through the PM's forward kinematics.

Measured: the orientation components ``components`` (subset of alpha, beta,
gamma in that order; default all three) and ``Qm``. Rows per pose, channels
named after the components: ``X_M - F(Qm, xi)`` (rad, wrapped), observation
matrix the matching rows of ``Psi^PKU = -J_e^b Psi^IKU`` (eqs. 123, 125-127) at
the FK solution. The numerical FK keeps each pose's assembly mode: it starts
from that pose's previous solution (:class:`~calibration.methods.pm_common.ModeKeepingFK`).

``start="robust"`` (default) first runs :func:`calibration.pm_start.robust_start_detail`
(a joint-space fit with the unmeasured angles as unknowns) so that the method
converges from the report's far nominal values; ``"nominal"`` starts at the
nominal values with the FK started at the measured components (0 for the others).
``q3_off, k3`` are not identifiable and are compensated (eqs. 112-113), N_R = 8
for 3, 2 or 1 components.
"""
from __future__ import annotations


from calibration.errors import CalibrationError
from calibration.methods import MethodData
from calibration.methods.pm_common import (COMPONENTS, STARTS, ModeKeepingFK, PMMethod,
                                           orientation_channel, parse_components, wrap)
from calibration.pm_start import guess_orientations, robust_start_detail


class ForwardKinematics(PMMethod):
    method = "pm-fk"

    def __init__(self, robot, qm, measured: dict, nominal, *, components=None,
                 start: str = "robust", start_options=None):
        super().__init__(robot, qm, nominal)
        if start not in STARTS:
            raise CalibrationError(f"start must be one of {STARTS}, not {start!r}")
        self.components = parse_components(components)
        self.comp_idx = [COMPONENTS.index(c) for c in self.components]
        self.X_m = orientation_channel(measured, self.components, self.method)
        self.start = None
        if start == "robust":
            data = MethodData(self.qm, {"orientation": self.X_m}, components=self.components)
            self.start = robust_start_detail(robot, data, self.nominal, self.components,
                                             options=start_options)
            self.x0, guess = self.start.x.copy(), self.start.X
        else:
            guess = guess_orientations(self.X_m, self.components)
        self.fk = ModeKeepingFK(robot, self.qm, guess)
        self._channels(self.components, list(range(len(self.components))))
        self.noise_groups = (self.channels,)  # one inclinometer's angles

    def evaluate(self, x):
        X = self.fk(x)
        r = wrap(self.X_m - X[:, self.comp_idx])
        W = self.robot.psi_pku(X, x, self.qm)[:, self.comp_idx, :]
        return r.reshape(-1), W.reshape(-1, self.nr)
