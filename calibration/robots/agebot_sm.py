"""The serial part (SM) of the AGEBOT: a linear rail plus a planar 3R arm.

docs/models.md, "Serial part (SM)" (report section 6, Table 2)::

    T_b4 = Rz(theta0) Tx(a0) * Tz(d1') Rz(pi/2 - theta0) * Rz(theta2) Tx(L2)
           * Rz(theta3) Tx(L3) * Rz(theta4) Tx(L4)

Joint coordinates ``Q = [d1', theta2, theta3, theta4]``, ``Q = K*Qm + Q_off``.
Generalized coordinates ``X = [x, y, z, phi]`` in the base frame: the rail
``z_b`` is horizontal, the arm moves in the vertical ``x_b-y_b`` plane and
``phi`` (angle of the last link from ``x_b``) is what an inclinometer on the
last link reads as its pitch.
"""
from __future__ import annotations

import math

import numpy as np

from calibration.chain import Chain, Factor
from calibration.errors import UnreachablePose
from calibration.robots.base import RobotModel

PARAM_NAMES = ("q1_off", "q2_off", "q3_off", "q4_off", "k1", "k2", "k3", "k4",
               "L2", "L3", "L4", "theta0", "a0")
TRUE = np.array([0.2, 0.3, 0.3, 0.2, 1 / 50, 1 / 110, 1 / 90, 1 / 85,
                 0.67, 0.44, 0.844, 1.1071, 0.44721])
NOMINAL = np.array([0.0, 0.0, 0.0, 0.0, 1 / 45, 1 / 100, 1 / 100, 1 / 100,
                    0.69, 0.46, 0.854, 1.1371, 0.54721])
# Joint limits (joint coordinates): rail travel in m, arm joints in rad.
JOINT_LIMITS = np.array([[-2.0, 2.0],
                         [-math.radians(170), math.radians(170)],
                         [-math.radians(170), math.radians(170)],
                         [-math.radians(170), math.radians(170)]])


def _chain() -> Chain:
    i = {n: k for k, n in enumerate(PARAM_NAMES)}
    f = (Factor("rz", terms=((i["theta0"], 1.0),)),
         Factor("tx", terms=((i["a0"], 1.0),)),
         Factor("tz", joint=0),
         Factor("rz", const=math.pi / 2, terms=((i["theta0"], -1.0),)),
         Factor("rz", joint=1), Factor("tx", terms=((i["L2"], 1.0),)),
         Factor("rz", joint=2), Factor("tx", terms=((i["L3"], 1.0),)),
         Factor("rz", joint=3), Factor("tx", terms=((i["L4"], 1.0),)))
    return Chain(f, len(PARAM_NAMES), offset_idx=(0, 1, 2, 3), gain_idx=(4, 5, 6, 7))


def wrap(a):
    """Angles wrapped to ``[-pi, pi)``."""
    return (np.asarray(a) + np.pi) % (2 * np.pi) - np.pi


class AgebotSM(RobotModel):
    name = "agebot-sm"
    param_names = PARAM_NAMES
    coords = ("x", "y", "z", "phi")
    angle_coords = (3,)
    group_rows = (0, 1)  # sm-self-redundancy: z holds only the rail (always singular)
    n_actuators = 4
    joint_limits = JOINT_LIMITS
    #: parameters that are angles (rad): compared modulo 2 pi, written wrapped to (-pi, pi]
    angle_params = ("q2_off", "q3_off", "q4_off", "theta0")

    def __init__(self):
        self.nominal = NOMINAL.copy()
        self.true = TRUE.copy()
        self.chain = _chain()

    # -- forward kinematics and its Jacobian ------------------------------------
    def fk(self, qm, xi) -> np.ndarray:
        """``X (m, 4) = [x, y, z, phi]`` for ``qm (m, 4)``; phi is not wrapped."""
        qm = np.atleast_2d(np.asarray(qm, dtype=float))
        T = self.chain.fk(qm, xi)
        q = self.chain.joints(qm, xi)
        phi = np.pi / 2 + q[:, 1] + q[:, 2] + q[:, 3]
        return np.column_stack([T[:, :3, 3], phi])

    def fk_jacobian(self, qm, xi):
        """``(X (m, 4), Psi (m, 4, N))``: rows x, y, z and the rotation about z_b."""
        qm = np.atleast_2d(np.asarray(qm, dtype=float))
        T, psi = self.chain.jacobian(qm, xi)
        q = self.chain.joints(qm, xi)
        phi = np.pi / 2 + q[:, 1] + q[:, 2] + q[:, 3]
        X = np.column_stack([T[:, :3, 3], phi])
        return X, psi[:, [0, 1, 2, 5], :]

    def base_offset(self, xi) -> np.ndarray:
        """Base offset ``(x0, y0, z0)`` of ``T_0^b`` (eq. 55): ``a0 (cos, sin) theta0``."""
        th, a = xi[self.index("theta0")], xi[self.index("a0")]
        return np.array([a * math.cos(th), a * math.sin(th), 0.0])

    def canonical(self, xi, frame_free: bool = False):
        """The one written form of equivalent parameter sets: lengths ``L2, L3, L4``
        and ``a0`` positive, angles wrapped to ``(-pi, pi]``. Exact equivalences of
        the FK (an iteration may end in either form):

        * ``(L2, q2_off, q3_off) ~ (-L2, q2_off + pi, q3_off + pi)``, likewise ``L3``
          with ``q3_off, q4_off``: ``Rz(t + pi) Tx(-L) = Rz(t) Tx(L) Rz(pi)``;
        * ``(theta0, a0) ~ (theta0 + pi, -a0)`` (the same base offset, eq. 55).

        frame_free: the measurements do not see the base frame turned by pi about
        ``z_b`` through its origin (distances to the origin or to a point of the arm,
        and phi modulo 2 pi: the distance methods); then also ``(L4, q4_off, q2_off,
        theta0) ~ (-L4, q4_off + pi, q2_off + pi, theta0 + pi)``, and the arm mirrored
        through the horizontal plane of the origin, ``(k1, q1_off) ~ (-k1, -q1_off)``
        (every other factor turns about or moves along the horizontal, so the rail
        running down instead of up changes no distance and no phi): ``k1`` positive,
        as the nominal has it (a session's final fit of a drawn arm ended there once
        in twenty, and the gate took the sign for a mis-wired reading).
        Returns ``(xi', s)``, ``s`` the sign of ``d xi' / d xi`` per parameter."""
        xi = np.array(xi, dtype=float)
        s = np.ones(len(xi))
        i = {n: self.index(n) for n in PARAM_NAMES}
        flips = [("L2", ("q2_off", "q3_off")), ("L3", ("q3_off", "q4_off"))]
        if frame_free:
            flips.insert(0, ("L4", ("q4_off", "q2_off", "theta0")))
        flips.append(("a0", ("theta0",)))
        for length, angles in flips:
            if xi[i[length]] < 0:
                xi[i[length]], s[i[length]] = -xi[i[length]], -s[i[length]]
                for a in angles:
                    xi[i[a]] += math.pi
        if frame_free and xi[i["k1"]] < 0:
            for n in ("k1", "q1_off"):
                xi[i[n]], s[i[n]] = -xi[i[n]], -s[i[n]]
        xi, _ = super().canonical(xi)
        return xi, s

    # -- inverse kinematics --------------------------------------------------------
    def ik_joints(self, X, xi, elbow: int = 1) -> np.ndarray:
        """Joint coordinates ``Q`` for one pose ``X = [x, y, z, phi]``.

        elbow: +1 chooses ``theta3 >= 0``, -1 ``theta3 <= 0``. Raises
        :class:`UnreachablePose` where the 2R sub-chain cannot reach the wrist or
        a joint leaves its limits.
        """
        x, y, z, phi = (float(v) for v in X)
        L2, L3, L4 = (xi[self.index(n)] for n in ("L2", "L3", "L4"))
        x0, y0, _ = self.base_offset(xi)
        px = x - L4 * math.cos(phi) - x0
        py = y - L4 * math.sin(phi) - y0
        c3 = (px * px + py * py - L2 * L2 - L3 * L3) / (2 * L2 * L3)
        if not -1.0 <= c3 <= 1.0:
            raise UnreachablePose(f"pose {np.round(X, 4).tolist()} is out of the arm's reach")
        th3 = math.copysign(math.acos(c3), elbow if elbow else 1)
        psi1 = math.atan2(py, px) - math.atan2(L3 * math.sin(th3), L2 + L3 * math.cos(th3))
        th2 = float(wrap(psi1 - math.pi / 2))
        th4 = float(wrap(phi - math.pi / 2 - th2 - th3))
        q = np.array([z, th2, th3, th4])
        lo, hi = self.joint_limits[:, 0], self.joint_limits[:, 1]
        if np.any(q < lo) or np.any(q > hi):
            raise UnreachablePose(f"pose {np.round(X, 4).tolist()} needs joints "
                                  f"{np.round(q, 4).tolist()} outside the joint limits")
        return q

    def ik_joints_many(self, X, xi, elbow: int = 1) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`ik_joints` of every row of ``X (m, 4)`` at once: ``(Q (m, 4), ok (m,))``,
        ``ok`` False (and ``Q`` meaningless) where that row raises :class:`UnreachablePose`."""
        X = np.atleast_2d(np.asarray(X, dtype=float))
        x, y, z, phi = X.T
        L2, L3, L4 = (xi[self.index(n)] for n in ("L2", "L3", "L4"))
        x0, y0, _ = self.base_offset(xi)
        px = x - L4 * np.cos(phi) - x0
        py = y - L4 * np.sin(phi) - y0
        c3 = (px * px + py * py - L2 * L2 - L3 * L3) / (2 * L2 * L3)
        ok = (c3 >= -1.0) & (c3 <= 1.0)
        th3 = np.copysign(np.arccos(np.clip(c3, -1.0, 1.0)), elbow if elbow else 1)
        psi1 = np.arctan2(py, px) - np.arctan2(L3 * np.sin(th3), L2 + L3 * np.cos(th3))
        th2 = wrap(psi1 - math.pi / 2)
        th4 = wrap(phi - math.pi / 2 - th2 - th3)
        q = np.column_stack([z, th2, th3, th4])
        lo, hi = self.joint_limits[:, 0], self.joint_limits[:, 1]
        ok &= np.all((q >= lo) & (q <= hi), axis=1)
        return q, ok

    def ik_many(self, X, xi, elbow: int | None = None) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`ik` of every row of ``X (m, 4)`` at once (a planner's candidates):
        ``(Qm (m, 4), ok (m,))``, ``Qm`` NaN where the row is unreachable."""
        q, ok = self.ik_joints_many(X, xi, 1 if elbow is None else elbow)
        if elbow is None:                       # elbow -1 where +1 cannot
            q2, ok2 = self.ik_joints_many(X, xi, -1)
            other = ~ok & ok2
            q[other], ok = q2[other], ok | ok2
        qm = self.chain.actuators(q, xi)
        qm[~ok] = np.nan
        return qm, ok

    def elbow_of(self, qm, xi) -> int:
        """Elbow of the configuration at actuator values ``qm``: +1 where theta3 >= 0."""
        q = self.chain.joints(np.atleast_2d(qm), xi)[0]
        return 1 if q[2] >= 0 else -1

    def move_to(self, qm, p, xi) -> np.ndarray:
        """Actuator values that put the end effector at ``p`` with the phi of the
        pose at ``qm`` (IK of ``xi``, elbow up where it can)."""
        phi = self.fk(qm, xi)[0, 3]
        return self.ik(np.r_[np.asarray(p, dtype=float)[:3], phi], xi)

    def ik(self, X, xi, elbow: int | None = None) -> np.ndarray:
        """Actuator values ``Qm (4,)`` for one pose ``X`` (eq. 57).

        elbow: +1 or -1; None tries +1, then -1 where +1 leaves the joint limits."""
        if elbow is None:
            try:
                q = self.ik_joints(X, xi, 1)
            except UnreachablePose:
                q = self.ik_joints(X, xi, -1)
        else:
            q = self.ik_joints(X, xi, elbow)
        return self.chain.actuators(q, xi)[0]
