"""The parallel part (PM) of the AGEBOT: a spherical wrist, 3 x PUS + passive S.

Calibration brief, section 2 (report sections 8-9). Base points ``B_i`` and
platform points ``D_i`` (platform frame F_e) on equilateral triangles of sides
``a1`` and ``a2``; platform centre fixed at ``O_e = (0, 0, v)``; orientation
``R = Rx(alpha) Ry(beta) Rz(gamma)``; slider i at ``C_i = B_i + (0, 0, q_i)``;
rods ``|D_i - C_i| = l``. Parameters
``a1, a2, l, v, q1_off, q2_off, q3_off, k1, k2, k3``.
"""
from __future__ import annotations

import math

import numpy as np

from calibration.errors import CalibrationError, UnreachablePose
from calibration.robots.base import RobotModel

PARAM_NAMES = ("a1", "a2", "l", "v", "q1_off", "q2_off", "q3_off", "k1", "k2", "k3")
TRUE = np.array([0.1298, 0.10108, 0.1465, 0.278, 0.02, 0.01, -0.01,
                 1 / 12000, 1 / 8000, 1 / 9000])
NOMINAL = np.array([0.1398, 0.1608, 0.1365, 0.270, 0.0, 0.0, 0.0,
                    1 / 11000, 1 / 7000, 1 / 10000])
S3 = math.sqrt(3.0)
# unit triangles: B_i = a1 * BU[i], D_i^e = a2 * DU[i]
BU = np.array([[S3 / 6, -0.5, 0.0], [S3 / 6, 0.5, 0.0], [-S3 / 3, 0.0, 0.0]])
DU = np.array([[S3 / 6, 0.5, 0.0], [-S3 / 3, 0.0, 0.0], [S3 / 6, -0.5, 0.0]])


def rot_xyz(X) -> np.ndarray:
    """``R = Rx(alpha) Ry(beta) Rz(gamma)`` for ``X (m, 3)``: ``(m, 3, 3)``."""
    X = np.atleast_2d(np.asarray(X, dtype=float))
    ca, sa = np.cos(X[:, 0]), np.sin(X[:, 0])
    cb, sb = np.cos(X[:, 1]), np.sin(X[:, 1])
    cg, sg = np.cos(X[:, 2]), np.sin(X[:, 2])
    R = np.empty((X.shape[0], 3, 3))
    R[:, 0, 0] = cb * cg
    R[:, 0, 1] = -cb * sg
    R[:, 0, 2] = sb
    R[:, 1, 0] = sa * sb * cg + ca * sg
    R[:, 1, 1] = -sa * sb * sg + ca * cg
    R[:, 1, 2] = -sa * cb
    R[:, 2, 0] = -ca * sb * cg + sa * sg
    R[:, 2, 1] = ca * sb * sg + sa * cg
    R[:, 2, 2] = ca * cb
    return R


def euler_rates(X) -> np.ndarray:
    """``H(X) (m, 3, 3)`` of eq. 118: angular velocity = H * d[alpha, beta, gamma]."""
    X = np.atleast_2d(np.asarray(X, dtype=float))
    ca, sa = np.cos(X[:, 0]), np.sin(X[:, 0])
    cb, sb = np.cos(X[:, 1]), np.sin(X[:, 1])
    H = np.zeros((X.shape[0], 3, 3))
    H[:, 0, 0] = 1.0
    H[:, 0, 2] = sb
    H[:, 1, 1] = ca
    H[:, 1, 2] = -sa * cb
    H[:, 2, 1] = sa
    H[:, 2, 2] = ca * cb
    return H


def _skew(v: np.ndarray) -> np.ndarray:
    S = np.zeros(v.shape[:-1] + (3, 3))
    S[..., 0, 1], S[..., 0, 2] = -v[..., 2], v[..., 1]
    S[..., 1, 0], S[..., 1, 2] = v[..., 2], -v[..., 0]
    S[..., 2, 0], S[..., 2, 1] = -v[..., 1], v[..., 0]
    return S


class AgebotPM(RobotModel):
    name = "agebot-pm"
    param_names = PARAM_NAMES
    coords = ("alpha", "beta", "gamma")
    n_actuators = 3

    def __init__(self):
        self.nominal = NOMINAL.copy()
        self.true = TRUE.copy()

    # -- geometry ---------------------------------------------------------------
    @staticmethod
    def _geometry(xi):
        a1, a2, l, v = (float(x) for x in xi[:4])
        return a1 * BU, a2 * DU, l, v

    def platform_points(self, X, xi):
        """``(r (m, 3, 3), D (m, 3, 3))``: ``R D_i^e`` and the world points ``D_i``."""
        B, De, l, v = self._geometry(xi)
        R = rot_xyz(X)
        r = np.einsum("mij,kj->mki", R, De)
        return r, r + np.array([0.0, 0.0, v])

    def ik_joints(self, X, xi, *, strict: bool = True):
        """Slider positions ``q (m, 3)`` for orientations ``X (m, 3)``.

        Returns ``(q, root)`` where ``root (m, 3)`` is ``l^2 - dx^2 - dy^2``; where
        it is negative the rod cannot reach and (if ``strict``) UnreachablePose is
        raised, else q there is NaN.
        """
        B, De, l, v = self._geometry(xi)
        _, D = self.platform_points(X, xi)
        d = D - B[None]
        root = l * l - d[..., 0] ** 2 - d[..., 1] ** 2
        if strict and np.any(root < 0):
            bad = np.argwhere(root < 0)[0]
            raise UnreachablePose(
                f"orientation {np.round(np.atleast_2d(X)[bad[0]], 4).tolist()}: rod "
                f"{bad[1] + 1} cannot reach its platform point")
        with np.errstate(invalid="ignore"):
            q = D[..., 2] - np.sqrt(root)
        return q, root

    def ik(self, X, xi, **_):
        """Actuator values ``Qm (3,)`` for one orientation (eq. 88)."""
        q, _ = self.ik_joints(np.atleast_2d(X), xi)
        k, off = np.asarray(xi[7:10]), np.asarray(xi[4:7])
        return ((q - off) / k)[0]

    def joints(self, qm, xi) -> np.ndarray:
        qm = np.atleast_2d(np.asarray(qm, dtype=float))
        return qm * np.asarray(xi[7:10]) + np.asarray(xi[4:7])

    def ik_x_jacobian(self, X, xi) -> np.ndarray:
        """``dq/dX (m, 3, 3)``: slider motion per Euler-angle change (inverse of the
        analytic Jacobian, eqs. 116-119)."""
        B, De, l, v = self._geometry(xi)
        r, D = self.platform_points(X, xi)
        d = D - B[None]
        s = np.sqrt(l * l - d[..., 0] ** 2 - d[..., 1] ** 2)
        n = np.stack([d[..., 0] / s, d[..., 1] / s, np.ones_like(s)], axis=-1)  # dq_i/dD_i
        # dD_i = w x r_i = -[r_i]x w,  w = H dX
        dDdw = -_skew(r)
        return np.einsum("mki,mkij,mjl->mkl", n, dDdw, euler_rates(X))

    def fk(self, qm, xi, guess=None, *, tol: float = 1e-13, max_iter: int = 50) -> np.ndarray:
        """Orientations ``X (m, 3)`` for ``qm (m, 3)`` by Newton on the IK equations.

        Each pose starts from ``guess`` (one orientation for all, or one per pose;
        default 0) and keeps that assembly mode. Raises :class:`CalibrationError`
        where the model cannot assemble (no real solution near the guess).
        """
        q_meas = self.joints(qm, xi)
        m = q_meas.shape[0]
        X = np.zeros((m, 3)) if guess is None else np.array(
            np.broadcast_to(np.asarray(guess, dtype=float), (m, 3)))
        for _ in range(max_iter):
            q, root = self.ik_joints(X, xi, strict=False)
            if np.any(root <= 0) or not np.all(np.isfinite(q)):
                raise CalibrationError("the PM model cannot assemble for these actuator "
                                       "values (a rod cannot reach its platform point)")
            g = q - q_meas
            if np.max(np.abs(g)) < tol:
                return X
            J = self.ik_x_jacobian(X, xi)
            try:
                step = np.linalg.solve(J, g[..., None])[..., 0]
            except np.linalg.LinAlgError:
                raise CalibrationError("the PM model is singular at these actuator values") from None
            # limit the step to keep the assembly mode of the start
            scale = np.minimum(1.0, 0.2 / np.maximum(np.abs(step).max(axis=1), 1e-300))
            X = X - step * scale[:, None]
        q, _ = self.ik_joints(X, xi, strict=False)
        if np.all(np.isfinite(q)) and np.max(np.abs(q - q_meas)) < 1e-9:
            return X
        raise CalibrationError("the PM forward kinematics did not converge: the model "
                               "cannot assemble at these actuator values")
