"""sm-distance (report 7.2): the distance from the end effector to a reference
point, reached beforehand at actuator values ``Qm_ref``, is measured.

Two residuals are offered:

* ``plain`` (default): ``D_M - D``. Its noise is the reading noise, the same
  for every pose, which is what eq. 51 (one sigma per channel) assumes; the
  reported std then matches the Monte Carlo scatter.
* ``squared`` (the report's eq. 63): ``D_M^2 - D^2``. Its noise is
  ``2 D sigma_D``, larger for far poses, so one sigma for all rows mis-weights
  them and the reported std no longer matches the scatter (see docs/methods.md).

``q1_off, q2_off, theta0, a0`` do not change any distance (no influence).
"""
from __future__ import annotations

import numpy as np

from calibration.errors import CalibrationError
from calibration.methods.base import RobotMethod, channel

RESIDUALS = ("plain", "squared")


def distance_rows(robot, qm, x, origin_qm, measured, residual):
    """Residuals and observation rows of distance readings to a point.

    origin_qm: actuator values at the reference point, or None for the
    base-frame origin (sm-distance-tilt)."""
    X, psi = robot.fk_jacobian(qm, x)
    p = X[:, :3]
    J = psi[:, :3, :]
    if origin_qm is not None:
        Xr, psir = robot.fk_jacobian(origin_qm, x)
        p = p - Xr[:, :3]
        J = J - psir[:, :3, :]
    D = np.linalg.norm(p, axis=1)
    if np.any(D < 1e-9):
        raise CalibrationError("a pose coincides with the reference point (distance 0): "
                               "its direction is undefined")
    if residual == "plain":
        return measured - D, np.einsum("mi,min->mn", p / D[:, None], J)
    return measured ** 2 - D ** 2, 2 * np.einsum("mi,min->mn", p, J)


class Distance(RobotMethod):
    method = "sm-distance"
    default_damping = 1e-2

    def __init__(self, robot, qm, measured: dict, nominal, *, reference_qm, residual="plain"):
        super().__init__(robot, qm, nominal)
        if residual not in RESIDUALS:
            raise CalibrationError(f"residual must be one of {RESIDUALS}, not {residual!r}")
        if reference_qm is None:
            raise CalibrationError("sm-distance needs the reference point's actuator values "
                                   "(a 'reference' record with role 'reference-point')")
        self.reference_qm = np.atleast_2d(np.asarray(reference_qm, dtype=float))
        self.D_m = channel(measured, "distance", self.method).reshape(-1)
        self.residual = residual
        self._channels(("distance",), [0])

    def evaluate(self, x):
        return distance_rows(self.robot, self.qm, x, self.reference_qm, self.D_m, self.residual)

    def residual_noise_gain(self, x):
        return np.ones(self.n_poses) if self.residual == "plain" else 2 * self.D_m
