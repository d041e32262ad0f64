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


def distance_rows(X, psi, origin, measured, residual):
    """Residuals and observation rows of distance readings to a point.

    X, psi: the poses' FK and generalized Jacobian; origin: ``(X_ref, psi_ref)``
    of the reference point, or None for the base-frame origin (sm-distance-tilt)."""
    p = X[:, :3]
    J = psi[:, :3, :]
    if origin is not None:
        p = p - origin[0][:, :3]
        J = J - origin[1][:, :3, :]
    D = np.linalg.norm(p, axis=1)
    if np.any(D < 1e-9):
        raise CalibrationError("a pose coincides with the reference point (distance 0): "
                               "its direction is undefined")
    if residual == "plain":
        return measured - D, np.einsum("mi,min->mn", p / D[:, None], J)
    return measured ** 2 - D ** 2, 2 * np.einsum("mi,min->mn", p, J)


def check_inputs(method: str, residual: str, reference_qm, what: str) -> np.ndarray:
    """Validate the residual choice and the reference actuator values of a
    distance method; returns the reference as a float array."""
    if residual not in RESIDUALS:
        raise CalibrationError(f"residual must be one of {RESIDUALS}, not {residual!r}")
    if reference_qm is None:
        raise CalibrationError(f"{method} needs {what}")
    return np.asarray(reference_qm, dtype=float)


class Distance(RobotMethod):
    method = "sm-distance"
    default_damping = 1e-2

    def __init__(self, robot, qm, measured: dict, nominal, *, reference_qm, residual="plain"):
        super().__init__(robot, qm, nominal)
        self.reference_qm = np.atleast_2d(check_inputs(
            self.method, residual, reference_qm, "the reference point's actuator values "
            "(a 'reference' record with role 'reference-point')"))
        self.D_m = channel(measured, "distance", self.method).reshape(-1)
        self.residual = residual
        self._channels(("distance",), [0])

    def evaluate(self, x):
        X, psi = self.robot.fk_jacobian(np.vstack([self.qm, self.reference_qm]), x)
        return distance_rows(X[:-1], psi[:-1], (X[-1:], psi[-1:]), self.D_m, self.residual)
