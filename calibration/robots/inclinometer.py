"""A physical dual-axis inclinometer on the tool: the two angles gravity shows it
(:func:`gravity_tilt`), on a mount turned by small angles, their heading, and their
Jacobians with respect to the tool's orientation (the tilt methods' rows:
:mod:`calibration.methods.sm_distance_tilt`, :mod:`calibration.methods.pm_tilt`)."""
from __future__ import annotations

import math

import numpy as np

from calibration.robots.rotations import _skew, euler_rates, rot_xyz


def _rx(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def _ry(b: float) -> np.ndarray:
    c, s = math.cos(b), math.sin(b)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def mount_rotation(mount) -> np.ndarray:
    """``R_mount = Rx(mx) Ry(my)`` (3, 3) of the inclinometer on the platform."""
    return _rx(float(mount[0])) @ _ry(float(mount[1]))


def gravity_tilt(R, mount=(0.0, 0.0)):
    """``(roll, pitch)`` in rad that a dual-axis inclinometer reads.

    The simulator (:mod:`drivers.sim.robot`) uses this same function:
    gravity ``(0, 0, -1)`` in F_b, in the sensor frame ``g_s = R_mount^T R^T (0, 0, -1)``
    with ``R_mount = Rx(mx) Ry(my)``; ``roll = atan2(-g_y, -g_z)``,
    ``pitch = atan2(g_x, sqrt(g_y^2 + g_z^2))``. Yaw about the vertical is not seen.

    R:     platform orientation, ``(3, 3)`` or ``(m, 3, 3)``.
    mount: ``(mx, my)`` rad.
    Returns two floats for one R, else two ``(m,)`` arrays.
    """
    R = np.asarray(R, dtype=float)
    single = R.ndim == 2
    R = R.reshape(-1, 3, 3)
    Rm = mount_rotation(mount)
    g = -np.einsum("ji,mj->mi", Rm, R[:, 2, :])  # R_mount^T R^T (0, 0, -1)
    roll = np.arctan2(-g[:, 1], -g[:, 2])
    pitch = np.arctan2(g[:, 0], np.hypot(g[:, 1], g[:, 2]))
    return (float(roll[0]), float(pitch[0])) if single else (roll, pitch)


def sensor_heading(R, mount=(0.0, 0.0)):
    """Yaw (rad) that an orientation sensor (AHRS) on the platform reports: the
    heading of ``R_s = R R_mount`` in the yaw-pitch-roll convention
    ``R_s = Rz(yaw) Ry(pitch) Rx(roll)``, whose roll and pitch are exactly
    :func:`gravity_tilt`. ``R`` ``(3, 3)`` or ``(m, 3, 3)``."""
    R = np.asarray(R, dtype=float)
    single = R.ndim == 2
    Rs = R.reshape(-1, 3, 3) @ mount_rotation(mount)
    yaw = np.arctan2(Rs[:, 1, 0], Rs[:, 0, 0])
    return float(yaw[0]) if single else yaw


def euler_from_ypr(roll, pitch, yaw) -> np.ndarray:
    """``[alpha, beta, gamma]`` of ``R = Rx(alpha) Ry(beta) Rz(gamma)`` (the report's
    convention) for a sensor reading ``R = Rz(yaw) Ry(pitch) Rx(roll)`` (rad):
    how an orientation sensor's output becomes the PM's measured orientation.
    Scalars give ``(3,)``, arrays ``(m, 3)``."""
    r, p, y = (np.asarray(v, dtype=float) for v in (roll, pitch, yaw))
    cr, sr, cp, sp, cy, sy = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
    # R = Rz(y) Ry(p) Rx(r); entries needed: R02, R12, R22, R01, R00
    r00, r01 = cy * cp, cy * sp * sr - sy * cr
    r02 = cy * sp * cr + sy * sr
    r12 = sy * sp * cr - cy * sr
    r22 = cp * cr
    out = np.stack([np.arctan2(-r12, r22), np.arcsin(np.clip(r02, -1.0, 1.0)),
                    np.arctan2(-r01, r00)], axis=-1)
    return out


def _tilt_of_gravity(g):
    """``(tilt (m, 2), d tilt / d g_s (m, 2, 3))`` for sensor-frame gravity ``g (m, 3)``."""
    gx, gy, gz = g[:, 0], g[:, 1], g[:, 2]
    rho2 = gy * gy + gz * gz
    rho = np.sqrt(rho2)
    n2 = gx * gx + rho2
    tilt = np.column_stack([np.arctan2(-gy, -gz), np.arctan2(gx, rho)])
    D = np.zeros((g.shape[0], 2, 3))
    D[:, 0, 1] = gz / rho2
    D[:, 0, 2] = -gy / rho2
    D[:, 1, 0] = rho / n2
    D[:, 1, 1] = -gx * gy / (rho * n2)
    D[:, 1, 2] = -gx * gz / (rho * n2)
    return tilt, D


def gravity_tilt_jacobian(R, mount=(0.0, 0.0)):
    """Inclinometer reading of orientations ``R (m, 3, 3)`` and its derivatives.

    Returns ``(tilt (m, 2), dT/dw (m, 2, 3), dT/dmount (m, 2, 2))`` with ``tilt =
    (roll, pitch)`` of :func:`gravity_tilt` and ``w`` a spatial rotation
    (``dR = [dw]x R``), so ``d(R^T e_z) = R^T [e_z]x dw``.
    """
    R = np.asarray(R, dtype=float).reshape(-1, 3, 3)
    mx, my = float(mount[0]), float(mount[1])
    Rm = mount_rotation(mount)
    gb = R[:, 2, :]  # R^T e_z, platform frame
    g = -gb @ Rm  # (Rm^T gb)^T, with the minus of gravity
    tilt, D = _tilt_of_gravity(g)
    ez = _skew(np.array([0.0, 0.0, 1.0]))
    dgb_dw = np.einsum("mji,jk->mik", R, ez)  # R^T [e_z]x
    dg_dw = -np.einsum("ji,mjl->mil", Rm, dgb_dw)
    c, s = math.cos(mx), math.sin(mx)
    dRx = np.array([[0.0, 0.0, 0.0], [0.0, -s, -c], [0.0, c, -s]])
    c, s = math.cos(my), math.sin(my)
    dRy = np.array([[-s, 0.0, c], [0.0, 0.0, 0.0], [-c, 0.0, -s]])
    dg_dm = np.stack([-gb @ (dRx @ _ry(my)), -gb @ (_rx(mx) @ dRy)], axis=-1)  # (m, 3, 2)
    return tilt, D @ dg_dw, D @ dg_dm


def tilt_jacobian(X, mount=(0.0, 0.0)):
    """Inclinometer reading of PM orientations and its derivatives.

    X: ``(m, 3)`` Euler angles. Returns ``(tilt (m, 2), dT/dX (m, 2, 3),
    dT/dmount (m, 2, 2))``: :func:`gravity_tilt_jacobian` with ``dw = H dX`` (eq. 118).
    """
    X = np.atleast_2d(np.asarray(X, dtype=float))
    tilt, dT_dw, dT_dm = gravity_tilt_jacobian(rot_xyz(X), mount)
    return tilt, dT_dw @ euler_rates(X), dT_dm
