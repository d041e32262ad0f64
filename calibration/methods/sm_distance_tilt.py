"""sm-distance-tilt (report 7.5): distance from a chosen base origin plus the
tilt ``phi`` of the last link.

The operator first brings the end effector to a point and records ``Qm_b``;
that point becomes the origin of a new base frame. The nominal ``theta0, a0,
q1_off`` are re-estimated for it (eqs. 76-77) before iterating, and the
calibrated values refer to it. Rows per pose: the distance residual (``plain``
``D_M - |X[1:3]|`` by default, or the report's ``D_M^2 - D^2``, eq. 83) and
``phi_M - phi``. All 13 parameters are identifiable; so is the draw-wire's
zero offset ``distance_off`` where the zero is a reading (``distance_zero =
"reading"``, see :mod:`calibration.methods.sm_distance`).
"""
from __future__ import annotations

import math

import numpy as np

from calibration.methods.base import RobotMethod, channel
from calibration.methods.sm_distance import check_inputs, distance_rows, with_zero, zero_names
from calibration.robots.agebot_pm import gravity_tilt_jacobian
from calibration.robots.agebot_sm import wrap

MOUNT = ("mount_x", "mount_y")  # the tool inclinometer's mounting rotation (robot files)


def reframe_nominal(robot, nominal: np.ndarray, origin_qm) -> np.ndarray:
    """Eqs. 76-77 and 55: the nominal ``theta0, a0, q1_off`` of the base frame
    whose origin is where the nominal model puts the end effector at ``origin_qm``."""
    x = np.array(nominal, dtype=float)
    p_b = robot.fk(np.atleast_2d(origin_qm), x)[0, :3]
    x0, y0, z0 = robot.base_offset(x) - p_b
    x[robot.index("theta0")] = math.atan2(y0, x0)
    x[robot.index("a0")] = math.hypot(x0, y0)
    x[robot.index("q1_off")] += z0
    return x


class DistanceTilt(RobotMethod):
    method = "sm-distance-tilt"
    default_damping = 1e-2

    def __init__(self, robot, qm, measured: dict, nominal, *, reference_qm,
                 residual="plain", reframe: bool = True, distance_zero="exact"):
        self.extra_names = zero_names(distance_zero)
        super().__init__(robot, qm, with_zero(robot, nominal, self.extra_names))
        self.reference_qm = check_inputs(
            self.method, residual, reference_qm, "the base origin's actuator values "
            "(a 'reference' record with role 'base-origin')").reshape(-1)
        self.D_m = channel(measured, "distance", self.method).reshape(-1)
        self.phi_m = channel(measured, "tilt", self.method).reshape(-1)
        self.residual = residual
        if reframe:
            self.x0[:self.nr] = reframe_nominal(robot, self.nominal[:self.nr], self.reference_qm)
        self._channels(("distance", "tilt"), [0, 1])

    def evaluate(self, x):
        X, psi = self.robot.fk_jacobian(self.qm, x[:self.nr])
        off = x[self.nr] if self.extra_names else None
        rd, Wd = distance_rows(X, psi, None, self.D_m, self.residual, off)
        rt = wrap(self.phi_m - X[:, 3])
        r = np.column_stack([rd, rt]).reshape(-1)
        Wt = np.zeros_like(Wd)
        Wt[:, :self.nr] = psi[:, 3, :]
        W = np.stack([Wd, Wt], axis=1).reshape(-1, self.n_params)
        return r, W


class InclinometerDistanceTilt(RobotMethod):
    """sm-distance-tilt on a robot file: the distance of the tool origin from the
    reference point (captured at ``reference_qm``, role ``base-origin``) plus a
    physical dual-axis inclinometer on the tool (trace channel ``tilt = [roll,
    pitch]``, :func:`calibration.robots.inclinometer.gravity_tilt` of the tool's
    orientation, gravity ``(0, 0, -1)`` of the base frame). Its mounting rotation
    ``R_mount = Rx(mount_x) Ry(mount_y)`` on the tool is calibrated too.

    Rows per pose: distance (as sm-distance), ``roll_M - roll``, ``pitch_M - pitch``
    (wrapped); the tilt rows' observation matrix ``dT/dw Psi_w`` for the robot
    and ``dT/dmount`` for the mount. A rotation about the vertical and the base's
    position are not seen. With ``distance_zero = "reading"`` the draw-wire's
    zero offset ``distance_off`` is calibrated too (before the mount), as on AGEBOT."""

    method = "sm-distance-tilt"
    default_damping = 1e-2

    def __init__(self, robot, qm, measured: dict, nominal, *, reference_qm, residual="plain",
                 distance_zero="exact"):
        zero = zero_names(distance_zero)
        self.extra_names = zero + MOUNT
        nominal = np.asarray(nominal, dtype=float)
        nr = robot.n_params
        if nominal.size == nr:
            nominal = np.r_[nominal, np.zeros(len(self.extra_names))]
        elif zero and nominal.size == nr + len(MOUNT):  # distance_off starts at 0
            nominal = np.r_[nominal[:nr], 0.0, nominal[nr:]]
        super().__init__(robot, qm, nominal)
        self.zero = bool(zero)
        self.reference_qm = np.atleast_2d(check_inputs(
            self.method, residual, reference_qm, "the reference point's actuator values "
            "(a 'reference' record with role 'base-origin')"))
        self.D_m = channel(measured, "distance", self.method).reshape(-1)
        self.T_m = channel(measured, "tilt", self.method, shape=(2,))
        self.residual = residual
        self._channels(("distance", "roll", "pitch"), [0, 1, 2])

    def evaluate(self, x):
        nr = self.nr
        xi, mount = x[:nr], x[-2:]
        off = x[nr] if self.zero else None
        T, psi = self.robot.spatial_jacobian(np.vstack([self.qm, self.reference_qm]), xi)
        p = T[:, :3, 3]
        rd, Wd = distance_rows(p[:-1], psi[:-1], (p[-1:], psi[-1:]), self.D_m, self.residual, off)
        tilt, dT_dw, dT_dm = gravity_tilt_jacobian(T[:-1, :3, :3], mount)
        rt = wrap(self.T_m - tilt)
        W = np.zeros((self.n_poses, 3, len(self.names)))
        W[:, 0, :Wd.shape[1]] = Wd
        W[:, 1:, :nr] = dT_dw @ psi[:-1, 3:]
        W[:, 1:, -2:] = dT_dm
        return np.column_stack([rd, rt]).reshape(-1), W.reshape(-1, len(self.names))
