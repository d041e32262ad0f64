"""Any serial manipulator of a robot file (report section 2; docs/robot-files.md).

The chain, base to tool (eqs. 1-9)::

    T_b^e = T_0^b * A_1 * ... * A_n * T_e^n
    T_0^b, T_e^n = Trans(z, d) Rot(z, theta) Trans(x, a) Rot(x, alpha) Trans(z, b) Rot(z, gamma)
    A_i (R)      = Trans(z, d_i) Rot(z, q_i) Trans(x, a_i) Rot(x, alpha_i)
    A_i (R, Hayati) = Rot(z, q_i) Trans(x, a_i) Rot(x, alpha_i) Rot(y, beta_i)
    A_i (P)      = Trans(z, q_i) Rot(z, theta_i) Trans(x, a_i) Rot(x, alpha_i)
    q_i = k_i * qm_i + q{i}_off                                          (eq. 9)

``Rot(y, beta)`` is written ``Rot(x, -pi/2) Rot(z, beta) Rot(x, pi/2)`` so that
the chain keeps its four elementary kinds. Every parameter of the spec is a
candidate; the identifiability analysis decides which are calibrated. They are
ordered as AGEBOT's: the offsets ``q{i}_off``, the ratios ``k{i}``, the links'
constants joint by joint, then base and tool. The unpivoted QR keeps the
earlier of two dependent parameters, so a joint's offset and ``d`` are kept and
the base's ``b, gamma`` (eq. 5) or the tool's ``a, alpha`` (eq. 7) are the ones
reported dependent.

Generalized coordinates ``X = [x, y, z, roll, pitch, yaw]`` of the tool frame
in the base frame, URDF convention ``R = Rz(yaw) Ry(pitch) Rx(roll)``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from calibration.chain import Chain, Factor
from calibration.errors import UnreachablePose
from calibration.robots.base import RobotModel

FRAME_KEYS = ("d", "theta", "a", "alpha", "b", "gamma")
FRAME_KINDS = ("tz", "rz", "tx", "rx", "tz", "rz")


@dataclass(frozen=True)
class JointSpec:
    """One joint of a robot file: nominal DH constants, transmission and limits.

    kind: ``"R"`` or ``"P"``. beta: Hayati's angle (R joints only; then ``d``
    is not used). limits: ``(lo, hi)`` of the actuator value ``qm``.
    """

    kind: str
    d: float = 0.0
    theta: float = 0.0
    a: float = 0.0
    alpha: float = 0.0
    beta: float | None = None
    k: float = 1.0
    offset: float = 0.0
    limits: tuple[float, float] = (-math.pi, math.pi)

    @property
    def hayati(self) -> bool:
        return self.beta is not None

    def constants(self, i: int) -> tuple[tuple[str, float], ...]:
        """``(name, nominal)`` of the link's constant parameters (spec's names)."""
        if self.kind == "P":
            return ((f"theta{i}", self.theta), (f"a{i}", self.a), (f"alpha{i}", self.alpha))
        if self.hayati:
            return ((f"a{i}", self.a), (f"alpha{i}", self.alpha), (f"beta{i}", self.beta))
        return ((f"d{i}", self.d), (f"a{i}", self.a), (f"alpha{i}", self.alpha))


@dataclass(frozen=True)
class SerialSpec:
    """A parsed robot file (pure data; drivers.robot_file reads the TOML)."""

    name: str
    joints: tuple[JointSpec, ...]
    base: tuple[float, ...] = (0.0,) * 6
    tool: tuple[float, ...] = (0.0,) * 6
    fixed: tuple[str, ...] = ()
    source: dict | None = field(default=None, compare=False)  # {name, sha256, text}


def param_layout(spec: SerialSpec) -> list[tuple[str, float]]:
    """``(name, nominal)`` of every parameter, in the model's order (module doc)."""
    js = list(enumerate(spec.joints, start=1))
    out = [(f"q{i}_off", jt.offset) for i, jt in js] + [(f"k{i}", jt.k) for i, jt in js]
    for i, jt in js:
        out.extend(jt.constants(i))
    out += [(f"base_{k}", v) for k, v in zip(FRAME_KEYS, spec.base)]
    out += [(f"tool_{k}", v) for k, v in zip(FRAME_KEYS, spec.tool)]
    return out


def build_chain(spec: SerialSpec, names: tuple[str, ...]) -> Chain:
    ix = {n: j for j, n in enumerate(names)}

    def p(name, kind, const=0.0, coef=1.0):
        return Factor(kind, const=const, terms=((ix[name], coef),))

    factors = [p(f"base_{k}", kd) for k, kd in zip(FRAME_KEYS, FRAME_KINDS)]
    for i, jt in enumerate(spec.joints, start=1):
        j = i - 1
        if jt.kind == "P":
            factors += [Factor("tz", joint=j), p(f"theta{i}", "rz"), p(f"a{i}", "tx"),
                        p(f"alpha{i}", "rx")]
        elif jt.hayati:
            factors += [Factor("rz", joint=j), p(f"a{i}", "tx"),
                        p(f"alpha{i}", "rx", const=-math.pi / 2), p(f"beta{i}", "rz"),
                        Factor("rx", const=math.pi / 2)]
        else:
            factors += [p(f"d{i}", "tz"), Factor("rz", joint=j), p(f"a{i}", "tx"),
                        p(f"alpha{i}", "rx")]
    factors += [p(f"tool_{k}", kd) for k, kd in zip(FRAME_KEYS, FRAME_KINDS)]
    n = len(spec.joints)
    return Chain(tuple(factors), len(names), offset_idx=tuple(ix[f"q{i}_off"] for i in range(1, n + 1)),
                 gain_idx=tuple(ix[f"k{i}"] for i in range(1, n + 1)))


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
    """The model of a robot file (module doc). ``nominal`` is the file's values;
    ``fixed`` the names the file holds at them."""

    kind = "serial"
    coords = ("x", "y", "z", "roll", "pitch", "yaw")
    angle_coords = (3, 4, 5)
    group_rows = (0, 1, 2)  # sm-self-redundancy compares the whole tool position

    def __init__(self, spec: SerialSpec):
        self.spec = spec
        self.name = spec.name
        layout = param_layout(spec)
        self.param_names = tuple(n for n, _ in layout)
        self.nominal = np.array([v for _, v in layout], dtype=float)
        self.true = self.nominal.copy()
        self.fixed = tuple(spec.fixed)
        self.n_actuators = len(spec.joints)
        self.limits = np.array([jt.limits for jt in spec.joints], dtype=float)
        self.chain = build_chain(spec, self.param_names)

    # -- kinematics -------------------------------------------------------------------
    def loads(self, qm):
        """The loads ``tau (m, n)`` that bend the joints at ``qm`` (a compliant model:
        :class:`calibration.robots.urdf.UrdfRobot`), else None."""
        return None

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
        """Conditioning warnings of the DH form: an R joint in DH form (its ``d`` not
        fixed) whose axis is (nearly) parallel to the next joint's (``|sin alpha_i| < tol``) has an
        ill-defined ``d`` (its common normal slides along the axes): a small
        misalignment needs a huge ``d`` and the fit is ill-conditioned."""
        out = []
        n = len(self.spec.joints)
        for i, jt in enumerate(self.spec.joints[:-1], start=1):
            if jt.kind == "R" and not jt.hayati and f"d{i}" not in self.fixed:
                alpha = float(xi[self.index(f"alpha{i}")])
                if abs(math.sin(alpha)) < tol and i < n:
                    out.append(f"joints {i} and {i + 1} of {self.name} have (nearly) parallel axes "
                               f"(alpha{i} = {alpha:.4g} rad) and joint {i} is in DH form: d{i} "
                               f"is ill-conditioned there (a small misalignment needs a huge "
                               f"d); give joint {i} Hayati's beta instead of d")
        return tuple(out)

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
