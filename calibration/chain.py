"""Serial kinematic chains as products of elementary transforms, with the
generalized Jacobian by the report's geometric method (eqs. 16-24).

A chain is a sequence of elementary transforms ``Trans(z)``, ``Rot(z)``,
``Trans(x)``, ``Rot(x)`` (the four factors of a DH matrix, eq. 1). The value of
each factor is affine in the calibrated parameters and in at most one joint
coordinate::

    value = const + sum(coef * xi[index]) + q[joint]
    q     = diag(K) * Qm + Q_off                                       (eq. 9)

This covers the DH convention with base and tool compensation (eqs. 3-7) and
models such as the AGEBOT arm whose ``theta0`` appears twice (``Rz(theta0)`` and
``Rz(pi/2 - theta0)``, report Table 2).

The generalized Jacobian is assembled column by column from the frames that
the forward kinematics already computes: a translation along axis ``u`` of the
frame before the factor contributes ``[u; 0]`` (eqs. 16, 18), a rotation about
``u`` through the frame origin ``o`` contributes ``[u x (p_e - o); u]``
(eqs. 17, 19); a transmission ratio ``k_i`` contributes the joint column times
``Qm[i]`` (eq. 23). No symbolic derivatives are needed.

Array shapes: ``m`` poses, ``n`` joints, ``N`` parameters. Units: metres and
radians; ``Qm`` in actuator units.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

KINDS = ("tz", "rz", "tx", "rx")


@dataclass(frozen=True)
class Factor:
    """One elementary transform of the chain.

    kind:  ``"tz"``, ``"rz"``, ``"tx"`` or ``"rx"``.
    const: constant part of the value (m or rad).
    terms: ``((param_index, coef), ...)``: the value's dependence on xi.
    joint: index of the joint coordinate added to the value, or None.
    """

    kind: str
    const: float = 0.0
    terms: tuple[tuple[int, float], ...] = ()
    joint: int | None = None

    def __post_init__(self):
        if self.kind not in KINDS:
            raise ValueError(f"factor kind must be one of {KINDS}, not {self.kind!r}")


@dataclass(frozen=True)
class Chain:
    """A serial chain ``T_b^e = prod(factors)`` with a linear transmission.

    factors:     the elementary transforms, base to tool.
    n_params:    length of the parameter vector ``xi``.
    offset_idx:  ``(n,)`` index in xi of each joint's offset ``q_off``, or -1 where
                 the offset is not a parameter (it is then 0).
    gain_idx:    ``(n,)`` index in xi of each joint's transmission ratio ``k``, or -1
                 where the ratio is fixed to 1 (the joint is driven directly).
    """

    factors: tuple[Factor, ...]
    n_params: int
    offset_idx: tuple[int, ...]
    gain_idx: tuple[int, ...]
    _cache: dict = field(default_factory=dict, compare=False, repr=False)

    @property
    def n_joints(self) -> int:
        return len(self.offset_idx)

    # -- joint space -------------------------------------------------------
    def joints(self, qm: np.ndarray, xi: np.ndarray) -> np.ndarray:
        """Joint coordinates ``Q = K*Qm + Q_off``: ``(m, n)`` from ``qm (m, n)``."""
        qm = np.atleast_2d(np.asarray(qm, dtype=float))
        xi = np.asarray(xi, dtype=float)
        k = np.array([xi[i] if i >= 0 else 1.0 for i in self.gain_idx])
        off = np.array([xi[i] if i >= 0 else 0.0 for i in self.offset_idx])
        return qm * k + off

    def actuators(self, q: np.ndarray, xi: np.ndarray) -> np.ndarray:
        """Actuator coordinates ``Qm = (Q - Q_off) / K`` (eq. 57)."""
        q = np.atleast_2d(np.asarray(q, dtype=float))
        xi = np.asarray(xi, dtype=float)
        k = np.array([xi[i] if i >= 0 else 1.0 for i in self.gain_idx])
        off = np.array([xi[i] if i >= 0 else 0.0 for i in self.offset_idx])
        return (q - off) / k

    # -- forward kinematics --------------------------------------------------
    def _values(self, q: np.ndarray, xi: np.ndarray) -> np.ndarray:
        """Factor values ``(m, F)`` for joint coordinates ``q (m, n)``."""
        m = q.shape[0]
        vals = np.empty((m, len(self.factors)))
        for j, f in enumerate(self.factors):
            v = f.const + sum(c * xi[i] for i, c in f.terms)
            vals[:, j] = v if f.joint is None else v + q[:, f.joint]
        return vals

    def frames(self, qm: np.ndarray, xi: np.ndarray):
        """Forward kinematics with the intermediate frames.

        Returns ``(T, before)``: ``T (m, 4, 4)`` the tool frame in the base frame,
        and ``before (m, F, 4, 4)`` the frame in which each factor acts (the
        product of all factors before it).
        """
        xi = np.asarray(xi, dtype=float)
        q = self.joints(qm, xi)
        vals = self._values(q, xi)
        m, nf = vals.shape
        before = np.empty((m, nf, 4, 4))
        T = np.broadcast_to(np.eye(4), (m, 4, 4)).copy()
        for j, f in enumerate(self.factors):
            before[:, j] = T
            v = vals[:, j]
            if f.kind in ("tz", "tx"):
                col = 2 if f.kind == "tz" else 0
                # T <- T * Trans(axis, v): origin moves along the frame's axis
                T[:, :3, 3] += T[:, :3, col] * v[:, None]
            else:
                c, s = np.cos(v)[:, None], np.sin(v)[:, None]
                if f.kind == "rz":  # columns x, y rotate about z
                    x, y = T[:, :3, 0].copy(), T[:, :3, 1].copy()
                    T[:, :3, 0] = c * x + s * y
                    T[:, :3, 1] = -s * x + c * y
                else:  # rx: columns y, z rotate about x
                    y, z = T[:, :3, 1].copy(), T[:, :3, 2].copy()
                    T[:, :3, 1] = c * y + s * z
                    T[:, :3, 2] = -s * y + c * z
        return T, before

    def fk(self, qm: np.ndarray, xi: np.ndarray) -> np.ndarray:
        """Tool frames ``(m, 4, 4)`` in the base frame."""
        return self.frames(qm, xi)[0]

    # -- generalized Jacobian ------------------------------------------------
    def factor_columns(self, T: np.ndarray, before: np.ndarray) -> np.ndarray:
        """Spatial columns ``(m, 6, F)``: tool displacement ``[dp; dw]`` per unit
        change of each factor's value (eqs. 16-19)."""
        m, nf = before.shape[:2]
        cols = np.zeros((m, 6, nf))
        p_e = T[:, :3, 3]
        for j, f in enumerate(self.factors):
            u = before[:, j, :3, 2 if f.kind in ("tz", "rz") else 0]
            if f.kind in ("tz", "tx"):
                cols[:, :3, j] = u
            else:
                v = p_e - before[:, j, :3, 3]  # u x v, written out (np.cross is slow on small arrays)
                cols[:, 0, j] = u[:, 1] * v[:, 2] - u[:, 2] * v[:, 1]
                cols[:, 1, j] = u[:, 2] * v[:, 0] - u[:, 0] * v[:, 2]
                cols[:, 2, j] = u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0]
                cols[:, 3:, j] = u
        return cols

    def jacobian(self, qm: np.ndarray, xi: np.ndarray):
        """Generalized Jacobian by the geometric method.

        Returns ``(T, Psi)``: tool frames ``(m, 4, 4)`` and ``Psi (m, 6, N)``, the
        spatial tool displacement ``[dp; dw]`` (base frame, dw a rotation vector)
        per unit change of each parameter (eq. 24).
        """
        qm = np.atleast_2d(np.asarray(qm, dtype=float))
        xi = np.asarray(xi, dtype=float)
        T, before = self.frames(qm, xi)
        cols = self.factor_columns(T, before)
        m = qm.shape[0]
        psi = np.zeros((m, 6, self.n_params))
        jac_q = np.zeros((m, 6, self.n_joints))  # kinematic Jacobian J(Q) (eq. 22)
        for j, f in enumerate(self.factors):
            for i, c in f.terms:
                psi[:, :, i] += c * cols[:, :, j]
            if f.joint is not None:
                jac_q[:, :, f.joint] += cols[:, :, j]
        for jt in range(self.n_joints):
            if self.offset_idx[jt] >= 0:
                psi[:, :, self.offset_idx[jt]] += jac_q[:, :, jt]
            if self.gain_idx[jt] >= 0:  # eq. 23: Psi_k = Psi_q * Qm[i]
                psi[:, :, self.gain_idx[jt]] += jac_q[:, :, jt] * qm[:, jt, None]
        return T, psi

    def joint_jacobian(self, qm: np.ndarray, xi: np.ndarray) -> np.ndarray:
        """Kinematic Jacobian ``J(Q) (m, 6, n)``: tool displacement per joint coordinate."""
        T, before = self.frames(qm, xi)
        cols = self.factor_columns(T, before)
        jac_q = np.zeros((cols.shape[0], 6, self.n_joints))
        for j, f in enumerate(self.factors):
            if f.joint is not None:
                jac_q[:, :, f.joint] += cols[:, :, j]
        return jac_q


@dataclass(frozen=True)
class DHJoint:
    """One DH link (eq. 1): ``Trans(z,d) Rot(z,theta) Trans(x,a) Rot(x,alpha)``.

    kind is ``"R"`` (theta is the joint coordinate) or ``"P"`` (d is).
    The numbers are the nominal geometry; the joint coordinate adds to theta or d.
    """

    kind: str
    d: float = 0.0
    theta: float = 0.0
    a: float = 0.0
    alpha: float = 0.0


@dataclass(frozen=True)
class DHModel:
    """A general DH serial chain with base and tool compensation (eqs. 3-8).

    ``names`` lists the calibrated parameters: the N = 4 n_R + 2 n_P + 6
    independent geometric ones (eq. 8; the offset of an R joint is its theta)
    followed by the n transmission ratios ``k1..kn``.
    """

    chain: Chain
    names: tuple[str, ...]
    nominal: np.ndarray

    @property
    def n_geometric(self) -> int:
        return len(self.names) - self.chain.n_joints


def dh_model(joints: list[DHJoint], base=(0.0, 0.0, 0.0, 0.0), tool=(0.0, 0.0),
             gains: list[float] | None = None) -> DHModel:
    """Build the general DH model of eqs. 3-8.

    base: nominal ``(d0, theta0, a0, alpha0)`` of ``T_0^b`` (``b0, gamma0`` merge
    into link 1, eq. 5). tool: nominal ``(b_e, gamma_e)`` of ``T_e^n``
    (``a_e, alpha_e`` merge into link n, eq. 7). gains: nominal ``k_i`` (1 by default).

    Calibrated: base ``d0 theta0 a0 alpha0``; for an R joint ``q{i}_off`` (its
    theta), ``d{i} a{i} alpha{i}``; for a P joint ``theta{i} alpha{i}`` (its d
    offset and a are not identifiable and stay fixed); tool ``b_e gamma_e``;
    then ``k1..kn``.
    """
    if not joints:
        raise ValueError("a chain needs at least one joint")
    names: list[str] = []
    nominal: list[float] = []

    def par(name: str, value: float) -> tuple[tuple[int, float], ...]:
        names.append(name)
        nominal.append(float(value))
        return ((len(names) - 1, 1.0),)

    factors = [Factor("tz", terms=par("d0", base[0])),
               Factor("rz", terms=par("theta0", base[1])),
               Factor("tx", terms=par("a0", base[2])),
               Factor("rx", terms=par("alpha0", base[3]))]
    offset_idx = []
    for i, jt in enumerate(joints, start=1):
        if jt.kind == "R":
            t_theta = par(f"q{i}_off", jt.theta)
            offset_idx.append(t_theta[0][0])
            factors += [Factor("tz", terms=par(f"d{i}", jt.d)),
                        Factor("rz", joint=i - 1)]
            # the offset enters through the transmission (Q = K Qm + Q_off)
            factors += [Factor("tx", terms=par(f"a{i}", jt.a)),
                        Factor("rx", terms=par(f"alpha{i}", jt.alpha))]
        elif jt.kind == "P":
            offset_idx.append(-1)
            factors += [Factor("tz", const=jt.d, joint=i - 1),
                        Factor("rz", terms=par(f"theta{i}", jt.theta)),
                        Factor("tx", const=jt.a),
                        Factor("rx", terms=par(f"alpha{i}", jt.alpha))]
        else:
            raise ValueError(f"joint {i}: kind must be 'R' or 'P', not {jt.kind!r}")
    factors += [Factor("tz", terms=par("b_e", tool[0])),
                Factor("rz", terms=par("gamma_e", tool[1]))]
    gain_idx = []
    gains = gains or [1.0] * len(joints)
    for i, g in enumerate(gains, start=1):
        gain_idx.append(par(f"k{i}", g)[0][0])
    chain = Chain(tuple(factors), len(names), tuple(offset_idx), tuple(gain_idx))
    return DHModel(chain, tuple(names), np.array(nominal))
