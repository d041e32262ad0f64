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

The draw-wire's zero (``distance_zero``): the sensor is zeroed at the
reference. ``"exact"`` (the report's model, and the default of a trace that
does not say otherwise) takes the reading there as exactly 0. ``"reading"``
takes it for what it is, one reading with noise: every distance then carries
the same unknown offset, calibrated as the extra parameter ``distance_off``
(m, the reading where the true distance is 0), so that the zero's noise
does not bias the robot's parameters (docs/methods.md, "Zeros and references").
"""
from __future__ import annotations

import numpy as np

from calibration.errors import CalibrationError
from calibration.methods.base import RobotMethod, channel

RESIDUALS = ("plain", "squared")
ZEROS = ("exact", "reading")
#: the extra parameter of a draw-wire zero that is a reading (m)
DISTANCE_OFF = "distance_off"


def distance_rows(X, psi, origin, measured, residual, offset=None):
    """Residuals and observation rows of distance readings to a point.

    X, psi: the poses' FK ``(m, 4)`` and generalized Jacobian ``(m, 4, N)``; origin:
    ``(X_ref, psi_ref)`` of the reference point, or None for the base-frame origin
    (sm-distance-tilt). offset: the reading at distance 0 (``distance_off``, m), or
    None where the zero is exact. Returns ``r (m,)`` and ``W (m, N)``, with one more
    column ``dD/d distance_off`` where ``offset`` is given."""
    p = X[:, :3]
    J = psi[:, :3, :]
    if origin is not None:
        p = p - origin[0][:, :3]
        J = J - origin[1][:, :3, :]
    D = np.linalg.norm(p, axis=1)
    if np.any(D < 1e-9):
        raise CalibrationError("a pose coincides with the reference point (distance 0): "
                               "its direction is undefined")
    u = np.einsum("mi,min->mn", p / D[:, None], J)       # dD/dx
    pred = D if offset is None else D + offset
    if residual == "plain":
        r, W, w_off = measured - pred, u, np.ones_like(D)
    else:
        r, W, w_off = measured ** 2 - pred ** 2, 2 * pred[:, None] * u, 2 * pred
    if offset is not None:
        W = np.column_stack([W, w_off])
    return r, W


def zero_names(distance_zero: str) -> tuple[str, ...]:
    """The extra parameters of a distance method for its draw-wire zero."""
    if distance_zero not in ZEROS:
        raise CalibrationError(f"distance_zero must be one of {ZEROS}, not {distance_zero!r}")
    return (DISTANCE_OFF,) if distance_zero == "reading" else ()


def with_zero(robot, nominal, extra_names) -> np.ndarray:
    """``nominal`` with the start value 0 of ``distance_off`` appended where it is
    calibrated and ``nominal`` holds only the robot's parameters."""
    nominal = np.asarray(nominal, dtype=float)
    if extra_names and nominal.shape == (robot.n_params,):
        return np.r_[nominal, 0.0]
    return nominal


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
    # not the report's 1e-2: at 1e-2 the first step from the nominal of an arm drawn
    # around it is nearly Gauss-Newton in a weak direction, and 29 of 1000 Monte Carlo
    # fits crawled to the iteration limit; at 0.2 none, with a sixth of the
    # evaluations, at the same minimum or a lower one in all but 1 of 2320 fits
    # (docs/methods.md)
    default_damping = 0.2

    def __init__(self, robot, qm, measured: dict, nominal, *, reference_qm, residual="plain",
                 distance_zero="exact"):
        self.extra_names = zero_names(distance_zero)
        super().__init__(robot, qm, with_zero(robot, nominal, self.extra_names))
        self.reference_qm = np.atleast_2d(check_inputs(
            self.method, residual, reference_qm, "the reference point's actuator values "
            "(a 'reference' record with role 'reference-point')"))
        self.D_m = channel(measured, "distance", self.method).reshape(-1)
        self.residual = residual
        self._channels(("distance",), [0])

    def evaluate(self, x):
        X, psi = self.robot.fk_jacobian(np.vstack([self.qm, self.reference_qm]), x[:self.nr])
        off = x[self.nr] if self.extra_names else None
        return distance_rows(X[:-1], psi[:-1], (X[-1:], psi[-1:]), self.D_m, self.residual, off)
