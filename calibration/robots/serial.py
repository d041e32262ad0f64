"""The model of a serial chain, whichever way it is written (report section 2).

A serial chain is a :class:`calibration.chain.Chain` of elementary factors, base to
tool, with a linear transmission::

    T = F_1(xi, q) * F_2(xi, q) * ... * F_K(xi, q)
    F_k = Trans(x|y|z, .) or Rot(x|y|z, .) of a constant, a parameter or a joint value
    q_i = k_i * qm_i + q{i}_off  (+ c{i} * tau_i where the joints bend)       (eq. 9)

It is written in one of two forms, each a small module that says how its spec becomes
the parameter layout, the chain, the held parameters and the labels (a
:class:`calibration.robots.written_form.WrittenForm`, the spec's ``form``):

* a robot file's DH/Hayati joints, :class:`SerialSpec`
  (:mod:`calibration.robots.dh_form`: eqs. 1-9, the parameters in AGEBOT's order);
* a URDF's chain from a base link to a tip link, :class:`calibration.robots.urdf.UrdfSpec`
  (:mod:`calibration.robots.urdf`: the joints' origins corrected in the joints' own
  frames, the instrument's frame first; optionally bending under gravity).

:class:`SerialRobot` is the one model of either: forward kinematics, the spatial and
generalized Jacobians, the numeric inverse kinematics. What only one form offers (a
URDF's ``calibrated_origins``, ``frame_matrix``, ``held_reason``, ``joint_label``) are
methods of the models of that form only, so ``hasattr`` tells the forms apart.

Generalized coordinates ``X = [x, y, z, roll, pitch, yaw]`` of the tool frame
in the base frame, URDF convention ``R = Rz(yaw) Ry(pitch) Rx(roll)``.
"""
from __future__ import annotations

from types import MethodType

import numpy as np

from calibration.errors import UnreachablePose
from calibration.robots.base import RobotModel
from calibration.robots.dh_form import (  # noqa: F401  (the robot file's names, read from here)
    FRAME_KEYS, FRAME_KINDS, JointSpec, SerialSpec, build_chain, param_layout)


def rpy_of(R: np.ndarray) -> np.ndarray:
    """``(m, 3)`` roll, pitch, yaw of ``R (m, 3, 3) = Rz(yaw) Ry(pitch) Rx(roll)``."""
    yaw = np.arctan2(R[:, 1, 0], R[:, 0, 0])
    pitch = np.arctan2(-R[:, 2, 0], np.hypot(R[:, 0, 0], R[:, 1, 0]))
    roll = np.arctan2(R[:, 2, 1], R[:, 2, 2])
    return np.column_stack([roll, pitch, yaw])


def rpy_matrix(rpy) -> np.ndarray:
    """``R (m, 3, 3) = Rz(yaw) Ry(pitch) Rx(roll)`` for ``rpy (m, 3)``."""
    rpy = np.atleast_2d(np.asarray(rpy, dtype=float))
    cr, sr = np.cos(rpy[:, 0]), np.sin(rpy[:, 0])
    cp, sp = np.cos(rpy[:, 1]), np.sin(rpy[:, 1])
    cy, sy = np.cos(rpy[:, 2]), np.sin(rpy[:, 2])
    R = np.empty((len(rpy), 3, 3))
    R[:, 0] = np.column_stack([cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr])
    R[:, 1] = np.column_stack([sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr])
    R[:, 2] = np.column_stack([-sp, cp * sr, cp * cr])
    return R


def rpy_rates(rpy: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Rates ``d(roll, pitch, yaw) (m, 3, N)`` of spatial rotations ``w (m, 3, N)``
    (the inverse of ``w = E(rpy) d rpy``; singular where ``cos(pitch) = 0``)."""
    cp, sp = np.cos(rpy[:, 1])[:, None], np.sin(rpy[:, 1])[:, None]
    cy, sy = np.cos(rpy[:, 2])[:, None], np.sin(rpy[:, 2])[:, None]
    wx, wy, wz = w[:, 0], w[:, 1], w[:, 2]
    h = (cy * wx + sy * wy) / cp
    return np.stack([h, -sy * wx + cy * wy, wz + sp * h], axis=1)


class SerialRobot(RobotModel):
    """The model of a serial chain written in any form (module doc): a robot file's
    ``SerialSpec`` or a URDF's ``UrdfSpec``. ``nominal`` is the spec's values;
    ``fixed`` the names held at them (the spec's, or its form's default)."""

    kind = "serial"
    coords = ("x", "y", "z", "roll", "pitch", "yaw")
    angle_coords = (3, 4, 5)
    group_rows = (0, 1, 2)  # sm-self-redundancy compares the whole tool position

    def __init__(self, spec):
        form = spec.form
        self.spec = spec
        self.name = spec.name
        layout = form.layout(spec)
        self.param_names = tuple(n for n, _ in layout)
        self.nominal = np.array([v for _, v in layout], dtype=float)
        self.true = self.nominal.copy()
        self.fixed = form.held(spec)
        self.n_actuators = len(spec.joints)
        self.limits = np.array([jt.limits for jt in spec.joints], dtype=float)
        self.chain = form.chain(spec, self.param_names)

    def __getattr__(self, name):
        """The written form's own operations (``WrittenForm.operations``), bound to this
        model; an AttributeError where the form has none of that name."""
        spec = self.__dict__.get("spec")      # absent while a copy or a pickle is rebuilt
        op = None if spec is None else spec.form.operations.get(name)
        if op is None:
            raise AttributeError(f"{type(self).__name__} {self.__dict__.get('name', '')!r} "
                                 f"has no attribute {name!r}")
        return MethodType(op, self)

    def __dir__(self):
        return sorted({*super().__dir__(), *self.spec.form.operations})

    # -- kinematics -------------------------------------------------------------------
    def loads(self, qm):
        """The loads ``tau (m, n)`` that bend the joints at ``qm`` (a compliant written
        form's: a URDF's with compliance, :func:`calibration.robots.urdf.gravity_loads`),
        else None."""
        loads = self.spec.form.loads
        return None if loads is None else loads(self, qm)

    def frames(self, qm, xi) -> np.ndarray:
        """Tool frames ``T (m, 4, 4)`` in the base frame."""
        qm = np.atleast_2d(np.asarray(qm, dtype=float))
        return self.chain.fk(qm, xi, tau=self.loads(qm))

    def fk(self, qm, xi) -> np.ndarray:
        """``X (m, 6) = [x, y, z, roll, pitch, yaw]`` for ``qm (m, n)``."""
        T = self.frames(qm, xi)
        return np.column_stack([T[:, :3, 3], rpy_of(T[:, :3, :3])])

    def spatial_jacobian(self, qm, xi):
        """``(T (m, 4, 4), Psi (m, 6, N))``: tool displacement ``[dp; dw]`` per parameter."""
        qm = np.atleast_2d(np.asarray(qm, dtype=float))
        return self.chain.jacobian(qm, xi, tau=self.loads(qm))

    def position_jacobian(self, qm, xi):
        """``(p (m, 3), dp/dxi (m, 3, N))`` (the chain's position rows only)."""
        qm = np.atleast_2d(np.asarray(qm, dtype=float))
        T, J = self.chain.jacobian(qm, xi, position_only=True, tau=self.loads(qm))
        return T[:, :3, 3], J

    def fk_jacobian(self, qm, xi):
        """``(X (m, 6), dX/dxi (m, 6, N))``, the angle rows by the rpy rates of ``dw``."""
        T, psi = self.spatial_jacobian(qm, xi)
        rpy = rpy_of(T[:, :3, :3])
        dX = np.concatenate([psi[:, :3], rpy_rates(rpy, psi[:, 3:])], axis=1)
        return np.column_stack([T[:, :3, 3], rpy]), dX

    def warnings(self, xi, tol: float = 0.05) -> tuple[str, ...]:
        """The written form's conditioning warnings at ``xi`` (the DH form's: a ``d`` on
        (nearly) parallel axes, :func:`calibration.robots.dh_form.dh_warnings`)."""
        warn = self.spec.form.warnings
        return () if warn is None else warn(self, xi, tol)

    # -- inverse kinematics (numeric) ----------------------------------------------------
    def move_to(self, qm, p, xi, *, tol: float = 1e-12, max_iter: int = 50) -> np.ndarray:
        """Actuator values near ``qm`` that put the tool origin at ``p`` (Gauss-Newton,
        minimum-norm steps, so the orientation changes as little as the arm allows).
        Raises :class:`UnreachablePose` where it does not converge or leaves the limits."""
        q = np.array(qm, dtype=float).reshape(-1)
        p = np.asarray(p, dtype=float)
        k = np.array([xi[i] for i in self.chain.gain_idx])
        for _ in range(max_iter):
            T = self.frames(q, xi)[0]
            e = p - T[:3, 3]
            if np.linalg.norm(e) < tol:
                break
            J = self.chain.joint_jacobian(q[None], xi, self.loads(q[None]))[0, :3] * k
            q = q + np.linalg.lstsq(J, e, rcond=1e-10)[0]
        else:
            raise UnreachablePose(f"no pose of {self.name} puts the tool at {np.round(p, 4).tolist()} "
                                  f"near the given one")
        if np.any(q < self.limits[:, 0]) or np.any(q > self.limits[:, 1]):
            raise UnreachablePose(f"the tool at {np.round(p, 4).tolist()} needs actuator values "
                                  f"{np.round(q, 4).tolist()} outside the limits")
        return q

    def ik(self, X, xi, guess=None, **_):
        """Actuator values for the tool position ``X[:3]`` near ``guess`` (default the
        middle of the limits); see :meth:`move_to`."""
        g = self.limits.mean(axis=1) if guess is None else guess
        return self.move_to(g, np.asarray(X, dtype=float)[:3], xi)
