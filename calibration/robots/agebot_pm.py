"""The parallel part (PM) of the AGEBOT: a spherical wrist, 3 x PUS + passive S.

docs/models.md, "Parallel part (PM)" (report sections 8-9). Base points ``B_i`` and
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
from calibration.robots.inclinometer import (  # noqa: F401 (importers use agebot_pm)
    mount_rotation, gravity_tilt, sensor_heading, euler_from_ypr, gravity_tilt_jacobian, tilt_jacobian)
from calibration.robots.rotations import (  # noqa: F401
    rot_xyz, euler_xyz, euler_rates, _skew)

PARAM_NAMES = ("a1", "a2", "l", "v", "q1_off", "q2_off", "q3_off", "k1", "k2", "k3")
TRUE = np.array([0.1298, 0.10108, 0.1465, 0.278, 0.02, 0.01, -0.01,
                 1 / 12000, 1 / 8000, 1 / 9000])
NOMINAL = np.array([0.1398, 0.1608, 0.1365, 0.270, 0.0, 0.0, 0.0,
                    1 / 11000, 1 / 7000, 1 / 10000])
S3 = math.sqrt(3.0)
# unit triangles: B_i = a1 * BU[i], D_i^e = a2 * DU[i]
BU = np.array([[S3 / 6, -0.5, 0.0], [S3 / 6, 0.5, 0.0], [-S3 / 3, 0.0, 0.0]])
DU = np.array([[S3 / 6, 0.5, 0.0], [-S3 / 3, 0.0, 0.0], [S3 / 6, -0.5, 0.0]])


class AgebotPM(RobotModel):
    name = "agebot-pm"
    kind = "parallel-wrist"
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
        return (n[:, :, None, :] @ dDdw)[:, :, 0, :] @ euler_rates(X)   # n^T dDdw H

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

    # -- calibration model (report section 9) -----------------------------------------
    def chain_jacobians(self, X, xi):
        """Per PUS chain (report Table 4, eq. 98): the DH joint angles and ``J_i3``.

        Returns ``(theta (m, 3, 2), J (m, 3, 3, 3), u (m, 3, 3))``: ``theta[..., 0:2] =
        (theta_i1, theta_i2)``, ``J[:, i]`` the chain Jacobian ``dD_i/d(l_i1, theta_i1,
        theta_i2)`` in F_i0 (axes of F_b, origin B_i) and ``u[:, i]`` the unit rod
        direction ``(D_i - C_i)/l = (c1 c2, s1 c2, s2)`` (= ``Psi_l^{i0}``, eq. 94).
        """
        B, De, l, v = self._geometry(xi)
        _, D = self.platform_points(X, xi)
        d = D - B[None]
        s = np.sqrt(l * l - d[..., 0] ** 2 - d[..., 1] ** 2)
        u = np.stack([d[..., 0] / l, d[..., 1] / l, s / l], axis=-1)
        t1 = np.arctan2(u[..., 1], u[..., 0])
        t2 = np.arctan2(u[..., 2], np.hypot(u[..., 0], u[..., 1]))
        s1, c1, s2, c2 = np.sin(t1), np.cos(t1), np.sin(t2), np.cos(t2)
        z = np.zeros_like(s1)
        J = np.stack([np.stack([z, -s1 * l * c2, -c1 * l * s2], -1),
                      np.stack([z, c1 * l * c2, -s1 * l * s2], -1),
                      np.stack([z + 1.0, z, l * c2], -1)], axis=-2)
        return np.stack([t1, t2], -1), J, u

    def psi_iku(self, X, xi, qm=None) -> np.ndarray:
        """Generalized Jacobian ``Psi^IKU (m, 3, 10)`` of eq. 106 at orientations ``X (m, 3)``.

        Row i is eq. 105: ``(J_i3)^-1[1,:] [Psi_a1 Psi_a2 -Psi_l Psi_v]`` (the change of
        the IK slider position ``q_i`` per change of ``a1, a2, l, v``), then ``-1`` for
        ``q_i_off`` and ``-qm_i`` for ``k_i``: the derivative of the joint-space closure
        ``Fbar^-1(X, a1, a2, l, v) - (K Qm + Q_off)`` with respect to xi. Without ``qm``
        the ``k_i`` columns hold ``-(q_i - q_i_off)/k_i`` (the actuator value the model
        ``xi`` itself gives at X, i.e. ``Qm = F^-1(X, xi)``).

        The first row of ``J_i3^-1`` is ``u_i^T / u_iz`` (the other two columns of
        ``J_i3`` are orthogonal to the rod direction u_i); it is computed so and
        checked against the explicit inverse in the tests.
        """
        X = np.atleast_2d(np.asarray(X, dtype=float))
        m = X.shape[0]
        R = rot_xyz(X)
        _, _, u = self.chain_jacobians(X, xi)
        jrow = u / u[..., 2:3]  # (J_i3)^-1 [1, :]   (m, 3, 3)
        psi_a1 = -np.broadcast_to(BU, (m, 3, 3))  # d O_e^{i0} / d a1 = -B_i / a1
        psi_a2 = np.einsum("mij,kj->mki", R, DU)  # d (R D_i^e) / d a2
        psi_v = np.broadcast_to(np.array([0.0, 0.0, 1.0]), (m, 3, 3))
        cols = np.stack([psi_a1, psi_a2, -u, psi_v], axis=-1)  # (m, 3 chains, 3 xyz, 4)
        P = np.zeros((m, 3, 10))
        P[..., :4] = np.einsum("mkj,mkjp->mkp", jrow, cols)
        idx = np.arange(3)
        P[:, idx, 4 + idx] = -1.0
        if qm is None:
            q, _ = self.ik_joints(X, xi, strict=False)
            qm = (q - np.asarray(xi[4:7])) / np.asarray(xi[7:10])
        P[:, idx, 7 + idx] = -np.atleast_2d(np.asarray(qm, dtype=float))
        return P

    def psi_pku(self, X, xi, qm=None) -> np.ndarray:
        """Generalized Jacobian ``Psi^PKU = -J_e^b Psi^IKU (m, 3, 10)`` (eq. 123):
        change of the FK orientation ``X = F(Qm, xi)`` per change of xi, at the
        FK solution ``X (m, 3)`` of ``qm``. ``J_e^b = (dq/dX)^-1`` (eq. 119)."""
        A = self.ik_x_jacobian(X, xi)  # dq/dX = (J_e^b)^-1
        return -np.linalg.solve(A, self.psi_iku(X, xi, qm))

    def ik_actuators(self, X, xi, *, strict: bool = True) -> np.ndarray:
        """Actuator values ``Qm (m, 3)`` for orientations ``X (m, 3)`` (eq. 88)."""
        q, _ = self.ik_joints(np.atleast_2d(X), xi, strict=strict)
        return (q - np.asarray(xi[4:7])) / np.asarray(xi[7:10])


# -- the wrist's physical envelope -------------------------------------------------------
#: Range of the passive joints (rad), what the station and the simulator hold the wrist
#: to: the rod's joint at the slider (rod from the slider's axis, the vertical), the
#: rod's joint at the platform (rod from the platform's normal) and the central
#: spherical joint (platform normal from the vertical). The report's +-20 deg box
#: needs at most about 67, 88 and 28 deg on wrists drawn around the report's.
PASSIVE_RANGE = {"slider joint": math.radians(80.0), "platform joint": math.radians(115.0),
                 "centre joint": math.radians(50.0)}


def passive_angles(X, xi) -> dict:
    """Angles of the passive joints (rad) at orientations ``X (m, 3)`` with the model
    ``xi``: ``"slider joint"`` and ``"platform joint"`` ``(m, 3)`` per rod, ``"centre
    joint"`` ``(m,)``; NaN where a rod cannot reach."""
    model = AgebotPM()
    X = np.atleast_2d(np.asarray(X, dtype=float))
    B, _, l, _ = model._geometry(xi)
    _, D = model.platform_points(X, xi)
    q, _ = model.ik_joints(X, xi, strict=False)
    u = (D - np.concatenate([np.broadcast_to(B[None, :, :2], D.shape[:2] + (2,)),
                             q[..., None]], axis=-1)) / l
    n = rot_xyz(X)[:, :, 2]
    with np.errstate(invalid="ignore"):
        return {"slider joint": np.arccos(np.clip(u[..., 2], -1, 1)),
                "platform joint": np.arccos(np.clip(np.einsum("mki,mi->mk", u, n), -1, 1)),
                "centre joint": np.arccos(np.clip(n[:, 2], -1, 1))}


def envelope_hit(X, xi, qm=None, qm_range=None) -> tuple[str, int, str] | None:
    """What the pose ``X (3,)`` of the model ``xi`` (actuator values ``qm (3,)``) would
    hit, or None: ``(kind, rod, text)`` with kind ``"reach"`` (a rod cannot reach its
    platform point), ``"stroke"`` (a slider outside ``qm_range (3, 2)``, actuator units)
    or a joint of :data:`PASSIVE_RANGE` outside its range; ``rod`` 0-based (the
    centre joint: the rod nearest its limit's direction, 0 if none)."""
    X = np.asarray(X, dtype=float).reshape(1, 3)
    if qm is None:
        qm = AgebotPM().ik_actuators(X, xi, strict=False)[0]
    qm = np.asarray(qm, dtype=float)
    if not np.all(np.isfinite(qm)):
        bad = int(np.flatnonzero(~np.isfinite(qm))[0])
        return "reach", bad, f"rod {bad + 1} cannot reach its platform point"
    if qm_range is not None:
        lo, hi = np.asarray(qm_range, dtype=float).T
        for i in np.flatnonzero((qm < lo) | (qm > hi)):
            return "stroke", int(i), (f"slider {i + 1} stroke ({qm[i]:.1f} outside "
                                      f"{lo[i]:g}..{hi[i]:g} actuator units)")
    for name, a in passive_angles(X, xi).items():
        a = np.atleast_1d(a[0])
        if np.any(a > PASSIVE_RANGE[name]):
            i = int(np.argmax(a)) if a.size > 1 else 0
            which = f" of rod {i + 1}" if a.size > 1 else ""
            return name, i, (f"{name}{which} range ({math.degrees(a[i]):.1f} deg, limit "
                             f"{math.degrees(PASSIVE_RANGE[name]):.0f})")
    return None



def beyond_envelope(X, xi, qm, qm_range=None) -> np.ndarray:
    """:func:`envelope_hit` for many poses at once, as yes or no: ``(m,)`` True where
    the pose ``X[i]`` (actuator values ``qm[i]``, both ``(m, 3)``) would hit something
    (the same comparisons: a rod that cannot reach, a slider outside ``qm_range``, a
    passive joint outside :data:`PASSIVE_RANGE`). :func:`envelope_hit` names what."""
    X = np.atleast_2d(np.asarray(X, dtype=float))
    qm = np.asarray(qm, dtype=float).reshape(len(X), 3)
    bad = ~np.isfinite(qm).all(axis=1)
    if qm_range is not None:
        lo, hi = np.asarray(qm_range, dtype=float).T
        bad |= ((qm < lo) | (qm > hi)).any(axis=1)
    for name, a in passive_angles(X, xi).items():
        bad |= (np.asarray(a).reshape(len(X), -1) > PASSIVE_RANGE[name]).any(axis=1)
    return bad

def envelope_violation(X, xi, qm=None, qm_range=None) -> str | None:
    """:func:`envelope_hit` in words (None: the pose is inside the envelope)."""
    hit = envelope_hit(X, xi, qm, qm_range)
    return None if hit is None else hit[2]
