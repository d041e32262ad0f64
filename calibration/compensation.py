"""Compensated targets: the actuator values that bring a calibrated model to where a
nominal model puts the tool (``app.py compensate``, docs/compensation.md).

A controller that takes no kinematic parameters runs its nominal model: at actuator
values ``qm`` it believes the tool is where the nominal model ``xi_nom`` puts it, the
*target*. The compensated values ``qm'`` are those at which the calibrated model
``xi_cal`` puts the tool there, found from ``qm`` itself (the same configuration, the
same elbow and wrist), inside the joint limits.

* A serial chain (a robot file's, a URDF's; :class:`SerialCompensation`): the tool is
  the chain's tip frame times a constant ``tool`` (4 x 4) of each model; the target is
  its point, and its orientation where the calibration determines it. Damped
  Gauss-Newton on the calibrated model, minimum-norm steps (a position target on a
  six-joint arm changes the orientation as little as it can), with the joint limits
  as bounds: a joint that reaches its limit is held there and the others go on; a
  target that cannot be reached so is *unreachable*, with the joint named.
* AGEBOT's arm (:class:`ArmCompensation`): ``X = [x, y, z, phi]``, its own analytic IK
  in the nominal configuration's elbow.
* AGEBOT's wrist (:class:`WristCompensation`): the orientation ``[alpha, beta, gamma]``,
  its own analytic IK, the passive joints' envelope.

Each ``predicted`` gives the calibration's own std of the tool where the compensated
values put it: the parameter file's covariance ``C`` over ``names`` through the
Jacobian of the tool with respect to the parameters.

Pure numerics: arrays in, arrays out. Units: metres, radians, actuator units.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from calibration.errors import CalibrationError, UnreachablePose

#: a target is reached where the calibrated model is this close to it (m, rad)
POS_TOL = 1e-6
ANG_TOL = 1e-6
#: Levenberg-Marquardt: iterations at most, the least and the most damping (m or rad
#: per joint unit), the share of the tolerances it iterates to, and the length that
#: weighs an orientation error against a position one (m per rad)
MAX_ITER = 100
DAMPING = 1e-9
MAX_DAMPING = 1e3
FINE = 1e-4
LENGTH = 1.0


@dataclass
class Solution:
    """One target compensated.

    qm:       the compensated actuator values (where unreachable: the start values);
    position: the calibrated model's remaining position error at ``qm`` (m; nan: none);
    angle:    its remaining orientation error (rad; nan where not compensated);
    reason:   None where the target is reached, else why not, in words;
    joint:    the joint (0-based) at its limit that stopped it, or None.
    """

    qm: np.ndarray
    position: float
    angle: float
    reason: str | None = None
    joint: int | None = None
    best: float = math.nan      # unreachable: the least position error reached (m)

    @property
    def ok(self) -> bool:
        return self.reason is None


def rotation_error(R_target: np.ndarray, R: np.ndarray) -> np.ndarray:
    """The spatial rotation vector ``w (3,)`` with ``R_target = exp([w]x) R``."""
    E = R_target @ R.T
    v = 0.5 * np.array([E[2, 1] - E[1, 2], E[0, 2] - E[2, 0], E[1, 0] - E[0, 1]])
    s = float(np.linalg.norm(v))
    angle = math.atan2(s, (float(np.trace(E)) - 1.0) / 2.0)
    return v * (angle / s) if s > 1e-300 else v


def rigid_fit(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """The rigid transform ``E (4, 4)`` with ``B ~ E A`` (points ``(M, 3)`` each, least
    squares, a proper rotation; Kabsch)."""
    ca, cb = A.mean(axis=0), B.mean(axis=0)
    U, _s, Vt = np.linalg.svd((A - ca).T @ (B - cb))
    d = np.sign(np.linalg.det(Vt.T @ U.T)) or 1.0
    E = np.eye(4)
    E[:3, :3] = Vt.T @ np.diag([1.0, 1.0, d]) @ U.T
    E[:3, 3] = cb - E[:3, :3] @ ca
    return E


def spans_plane(points: np.ndarray, spread: float = 5e-3) -> bool:
    """Whether points ``(M, 3)`` fix a rigid body's orientation: three or more, not on
    one line (their RMS distance from the best line at least ``spread``, m)."""
    P = np.asarray(points, dtype=float)
    if len(P) < 3:
        return False
    s = np.linalg.svd(P - P.mean(axis=0), compute_uv=False)
    return float(s[1]) / math.sqrt(len(P)) >= spread


def _cov(J: np.ndarray, names, C) -> np.ndarray:
    """``J C J^T`` for ``J (k, len(names))`` over the covariance's parameters."""
    return J @ np.asarray(C, dtype=float) @ J.T if len(names) else np.zeros((len(J),) * 2)


class SerialCompensation:
    """A serial chain's targets and compensation (module doc).

    robot:       a :class:`calibration.robots.serial.SerialRobot`;
    xi_nom, xi_cal: the nominal and the calibrated parameters (the frame the targets
                 are in: for a URDF robot measured in an instrument's frame, its
                 ``base_*`` zeroed in both);
    tool_nom, tool_cal: ``(4, 4)`` the tool in each model's tip frame (default identity);
    orientation: whether the target's orientation is compensated too;
    limits:      ``(n, 2)`` actuator bounds (inf where a joint has none);
    xi_pred, point_params: the calibrated values the covariance is about (the frame
                 included) and, where the tool point is the mean of points on the tool
                 that are parameters of the method (sm-markers), their names in order
                 (``[(x, y, z) names per point]``).
    """

    def __init__(self, robot, xi_nom, xi_cal, *, tool_nom=None, tool_cal=None,
                 orientation: bool = False, limits=None, xi_pred=None, point_params=()):
        self.robot = robot
        self.xi_nom = np.asarray(xi_nom, dtype=float)
        self.xi_cal = np.asarray(xi_cal, dtype=float)
        self.tool_nom = np.eye(4) if tool_nom is None else np.asarray(tool_nom, dtype=float)
        self.tool_cal = np.eye(4) if tool_cal is None else np.asarray(tool_cal, dtype=float)
        self.orientation = bool(orientation)
        n = robot.n_actuators
        lim = robot.limits if limits is None else limits
        self.limits = np.asarray(lim, dtype=float).reshape(n, 2)
        self.xi_pred = self.xi_cal if xi_pred is None else np.asarray(xi_pred, dtype=float)
        self.point_params = tuple(point_params)
        self.gains = np.array([self.xi_cal[i] if i >= 0 else 1.0
                               for i in robot.chain.gain_idx])

    # -- the targets -------------------------------------------------------------------
    def targets(self, qm) -> np.ndarray:
        """``(m, 4, 4)`` the tool frames of the nominal model at ``qm (m, n)``."""
        return self.robot.frames(np.atleast_2d(qm), self.xi_nom) @ self.tool_nom

    def errors(self, qm, target) -> tuple[float, float]:
        """``(position m, angle rad)`` of the calibrated model's tool at ``qm (n,)`` from
        ``target (4, 4)`` (angle nan where the orientation is not compensated)."""
        T = self.robot.frames(np.atleast_2d(qm), self.xi_cal)[0] @ self.tool_cal
        pos = float(np.linalg.norm(target[:3, 3] - T[:3, 3]))
        if not self.orientation:
            return pos, math.nan
        return pos, float(np.linalg.norm(rotation_error(target[:3, :3], T[:3, :3])))

    # -- Gauss-Newton ------------------------------------------------------------------
    def _residual(self, q, target):
        T = self.robot.frames(q[None], self.xi_cal)[0] @ self.tool_cal
        e = target[:3, 3] - T[:3, 3]
        if self.orientation:
            e = np.r_[e, LENGTH * rotation_error(target[:3, :3], T[:3, :3])]
        return e, T

    def _jacobian(self, q, T):
        """``d(tool point[, orientation]) / d qm`` (``(3 or 6, n)``)."""
        rob = self.robot
        J = rob.chain.joint_jacobian(q[None], self.xi_cal, rob.loads(q[None]))[0] * self.gains
        tip = rob.frames(q[None], self.xi_cal)[0]
        arm = T[:3, 3] - tip[:3, 3]                     # tip origin -> tool point
        Jp = J[:3] + np.cross(J[3:].T, arm).T           # v + w x arm
        return np.r_[Jp, LENGTH * J[3:]] if self.orientation else Jp

    def solve(self, qm0, target) -> Solution:
        """The actuator values near ``qm0 (n,)`` that bring the calibrated model's tool to
        ``target (4, 4)`` within :attr:`limits` (module doc): Levenberg-Marquardt steps
        (minimum norm where the joints are more than the target needs), a joint that
        would pass its limit held at it while the others go on."""
        lo, hi = self.limits[:, 0], self.limits[:, 1]
        q = np.clip(np.asarray(qm0, dtype=float), lo, hi)
        e, T = self._residual(q, target)
        cost, lam = float(e @ e), DAMPING
        for _ in range(MAX_ITER):
            if self._reached(e, FINE):
                break
            J = self._jacobian(q, T)
            g = J.T @ e
            free = ~(((q <= lo) & (g < 0)) | ((q >= hi) & (g > 0)))
            if not free.any():
                break
            U, s, Vt = np.linalg.svd(J[:, free], full_matrices=False)
            while lam < MAX_DAMPING:
                dq = np.zeros_like(q)
                dq[free] = Vt.T @ ((s / (s * s + lam * lam)) * (U.T @ e))
                q_try = np.clip(q + dq, lo, hi)
                e_try, T_try = self._residual(q_try, target)
                c_try = float(e_try @ e_try)
                if c_try < cost:
                    break
                lam *= 10.0
            else:
                break
            q, e, T, cost, lam = q_try, e_try, T_try, c_try, max(lam / 10.0, DAMPING)
        pos, ang = self.errors(q, target)
        if self._reached(e):
            return Solution(q, pos, ang)
        at = np.flatnonzero((q <= lo) | (q >= hi))
        joint = int(at[0]) if at.size else None
        if joint is not None:
            side = "upper" if q[joint] >= hi[joint] else "lower"
            reason = f"joint {joint + 1} at its {side} limit"
        else:
            reason = "no convergence (out of the calibrated robot's reach, or a singularity)"
        return Solution(np.asarray(qm0, dtype=float), *self.errors(qm0, target), reason, joint,
                        best=pos)

    def _reached(self, e, share: float = 1.0) -> bool:
        ok = float(np.linalg.norm(e[:3])) < share * POS_TOL
        return ok and (not self.orientation
                       or float(np.linalg.norm(e[3:])) < share * LENGTH * ANG_TOL)

    # -- what the calibration predicts there -----------------------------------------------
    def predicted(self, qm, names, C) -> tuple[np.ndarray, np.ndarray]:
        """``(position std (m,), orientation std (m,))`` (m, rad; the 3D std, the square
        root of the covariance's trace) of the calibrated tool at ``qm (m, n)``; the
        orientation's nan where it is not compensated or the tool's turn depends on
        points on the tool (sm-markers)."""
        rob, qm = self.robot, np.atleast_2d(np.asarray(qm, dtype=float))
        n = rob.n_params
        T, psi = rob.spatial_jacobian(qm, self.xi_pred[:n])
        pts = len(self.point_params)
        if pts:
            u = self.xi_pred[n:].reshape(pts, 3)
            arm = np.einsum("mij,j->mi", T[:, :3, :3], u.mean(axis=0))
        else:
            arm = np.einsum("mij,j->mi", T[:, :3, :3], self.tool_cal[:3, 3])
        Jp = psi[:, :3] + np.cross(psi[:, 3:].transpose(0, 2, 1), arm[:, None, :]).transpose(0, 2, 1)
        col = {nm: j for j, nm in enumerate(names)}
        sp, sa = np.empty(len(qm)), np.full(len(qm), math.nan)
        for k in range(len(qm)):
            Jk = np.zeros((3, len(names)))
            Jw = np.zeros((3, len(names)))
            for j, nm in enumerate(rob.param_names):
                if nm in col:
                    Jk[:, col[nm]] = Jp[k, :, j]
                    Jw[:, col[nm]] = psi[k, 3:, j]
            for trio in self.point_params:          # the mean point: R / M per point
                for a, nm in enumerate(trio):
                    if nm in col:
                        Jk[:, col[nm]] = T[k, :3, a] / pts
            sp[k] = math.sqrt(max(float(np.trace(_cov(Jk, names, C))), 0.0))
            if self.orientation and not pts:
                sa[k] = math.sqrt(max(float(np.trace(_cov(Jw, names, C))), 0.0))
        return sp, sa


class _BuiltinCompensation:
    """A built-in robot's nominal and calibrated models (its own ``fk`` and ``ik``):
    ``xi_nom`` puts the targets, ``xi_cal`` reaches them, ``xi_pred`` (default
    ``xi_cal``) predicts the remaining error."""

    orientation = True

    def __init__(self, robot, xi_nom, xi_cal, xi_pred=None):
        self.robot = robot
        self.xi_nom = np.asarray(xi_nom, dtype=float)
        self.xi_cal = np.asarray(xi_cal, dtype=float)
        self.xi_pred = self.xi_cal if xi_pred is None else np.asarray(xi_pred, dtype=float)

    def targets(self, qm) -> np.ndarray:
        """Where the nominal model puts the tool (the arm's ``[x, y, z, phi]``, the wrist's
        orientation) at ``qm (m, n)``; the wrist raises :class:`CalibrationError` where
        the nominal wrist cannot assemble at a row's values."""
        return self.robot.fk(np.atleast_2d(qm), self.xi_nom)


class ArmCompensation(_BuiltinCompensation):
    """AGEBOT's arm (:class:`calibration.robots.agebot_sm.AgebotSM`): the targets
    ``X = [x, y, z, phi]`` of the nominal model, reached by the calibrated model's IK in
    the elbow of the nominal configuration (its four joints set the point and phi)."""

    def errors(self, qm, target) -> tuple[float, float]:
        X = self.robot.fk(np.atleast_2d(qm), self.xi_cal)[0]
        d = (X[3] - target[3] + math.pi) % (2 * math.pi) - math.pi
        return float(np.linalg.norm(X[:3] - target[:3])), abs(float(d))

    def solve(self, qm0, target) -> Solution:
        elbow = self.robot.elbow_of(qm0, self.xi_nom)
        try:
            q = self.robot.ik(target, self.xi_cal, elbow=elbow)
        except UnreachablePose as e:
            why = "out of the arm's reach" if "reach" in str(e) else "a joint beyond its limit"
            return Solution(np.asarray(qm0, dtype=float), *self.errors(qm0, target),
                            f"{why} (elbow {'up' if elbow > 0 else 'down'})")
        pos, ang = self.errors(q, target)
        if pos >= POS_TOL or ang >= ANG_TOL:
            return Solution(np.asarray(qm0, dtype=float), *self.errors(qm0, target),
                            "no convergence")
        return Solution(q, pos, ang)

    def predicted(self, qm, names, C):
        """``(position std, phi std)`` of the calibrated arm at ``qm (m, 4)``."""
        qm = np.atleast_2d(np.asarray(qm, dtype=float))
        _X, psi = self.robot.fk_jacobian(qm, self.xi_pred[:self.robot.n_params])
        J = _columns(psi, self.robot.param_names, names)
        return (np.sqrt([max(float(np.trace(_cov(J[k, :3], names, C))), 0.0)
                         for k in range(len(qm))]),
                np.sqrt([max(float(_cov(J[k, 3:], names, C)[0, 0]), 0.0)
                         for k in range(len(qm))]))


def _columns(J, have, names) -> np.ndarray:
    """``J (m, r, len(have))`` rearranged over ``names`` (0 where not a column of J)."""
    out = np.zeros(J.shape[:2] + (len(names),))
    for j, nm in enumerate(names):
        if nm in have:
            out[:, :, j] = J[:, :, list(have).index(nm)]
    return out


class WristCompensation(_BuiltinCompensation):
    """AGEBOT's wrist (:class:`calibration.robots.agebot_pm.AgebotPM`): the orientation
    ``[alpha, beta, gamma]`` the nominal model assembles to at ``qm``, reached by the
    calibrated model's IK and inside the passive joints' envelope."""

    def errors(self, qm, target) -> tuple[float, float]:
        from calibration.robots.agebot_pm import rot_xyz

        try:
            X = self.robot.fk(np.atleast_2d(qm), self.xi_cal, guess=target)[0]
        except CalibrationError:
            return math.nan, math.nan
        w = rotation_error(rot_xyz(target)[0], rot_xyz(X)[0])
        return math.nan, float(np.linalg.norm(w))

    def solve(self, qm0, target) -> Solution:
        from calibration.robots.agebot_pm import envelope_hit

        try:
            qm = self.robot.ik(target, self.xi_cal)
        except UnreachablePose as e:
            return Solution(np.asarray(qm0, dtype=float), *self.errors(qm0, target), str(e))
        hit = envelope_hit(target, self.xi_cal, qm)
        if hit is not None:
            return Solution(np.asarray(qm0, dtype=float), *self.errors(qm0, target),
                            f"beyond the wrist's {hit[2]}")
        _pos, ang = self.errors(qm, target)
        if not ang < ANG_TOL:
            return Solution(np.asarray(qm0, dtype=float), *self.errors(qm0, target),
                            "no convergence")
        return Solution(qm, math.nan, ang)

    def predicted(self, qm, names, C):
        """``(nan, orientation std)`` of the calibrated wrist at ``qm (m, 3)``."""
        from calibration.robots.agebot_pm import euler_rates

        qm = np.atleast_2d(np.asarray(qm, dtype=float))
        rob, x = self.robot, self.xi_pred[:self.robot.n_params]
        X = rob.fk(qm, x)
        W = euler_rates(X) @ rob.psi_pku(X, x, qm)          # angular velocity per parameter
        J = _columns(W, rob.param_names, names)
        return (np.full(len(qm), math.nan),
                np.sqrt([max(float(np.trace(_cov(J[k], names, C))), 0.0)
                         for k in range(len(qm))]))
