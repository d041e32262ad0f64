"""Serial kinematic chains as products of elementary transforms, with the
generalized Jacobian by the report's geometric method (eqs. 16-24).

A chain is a sequence of elementary transforms ``Trans(z)``, ``Rot(z)``,
``Trans(x)``, ``Rot(x)`` (the four factors of a DH matrix, eq. 1), and
``Trans(y)``, ``Rot(y)`` (Hayati's ``beta`` for parallel axes). The value of
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

Evaluation is vectorized over the poses: the chain is compiled once
(:class:`_Plan`: the factors' values as one matrix product, the parameter
columns as another), the forward kinematics takes one step of a few vector
operations per factor for all poses together, and the Jacobian's columns of
all factors come at once from the axes and origins that sweep leaves behind.

Array shapes: ``m`` poses, ``n`` joints, ``N`` parameters, ``F`` factors.
Units: metres and radians; ``Qm`` in actuator units.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

KINDS = ("tz", "rz", "tx", "rx", "ty", "ry")


@dataclass(frozen=True)
class Factor:
    """One elementary transform of the chain.

    kind:  ``"tz"``, ``"rz"``, ``"tx"``, ``"rx"``, ``"ty"`` or ``"ry"``.
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
    comp_idx:    ``(n,)`` index in xi of each joint's compliance ``c`` (its deflection
                 per unit of the load ``tau`` given per pose: ``q = k Qm + Q_off + c tau``),
                 or -1; empty: no compliance.
    """

    factors: tuple[Factor, ...]
    n_params: int
    offset_idx: tuple[int, ...]
    gain_idx: tuple[int, ...]
    comp_idx: tuple[int, ...] = ()
    _cache: dict = field(default_factory=dict, compare=False, repr=False)

    @property
    def n_joints(self) -> int:
        return len(self.offset_idx)

    # -- joint space -------------------------------------------------------
    def joints(self, qm: np.ndarray, xi: np.ndarray, tau=None) -> np.ndarray:
        """Joint coordinates ``Q = K*Qm + Q_off`` (``+ C*tau`` with compliance and the
        loads ``tau (m, n)``): ``(m, n)`` from ``qm (m, n)``."""
        qm = np.atleast_2d(np.asarray(qm, dtype=float))
        xi = np.asarray(xi, dtype=float)
        k = np.array([xi[i] if i >= 0 else 1.0 for i in self.gain_idx])
        off = np.array([xi[i] if i >= 0 else 0.0 for i in self.offset_idx])
        q = qm * k + off
        if tau is not None and self.comp_idx:
            c = np.array([xi[i] if i >= 0 else 0.0 for i in self.comp_idx])
            q = q + np.atleast_2d(tau) * c
        return q

    def actuators(self, q: np.ndarray, xi: np.ndarray) -> np.ndarray:
        """Actuator coordinates ``Qm = (Q - Q_off) / K`` (eq. 57)."""
        q = np.atleast_2d(np.asarray(q, dtype=float))
        xi = np.asarray(xi, dtype=float)
        k = np.array([xi[i] if i >= 0 else 1.0 for i in self.gain_idx])
        off = np.array([xi[i] if i >= 0 else 0.0 for i in self.offset_idx])
        return (q - off) / k

    # -- forward kinematics --------------------------------------------------
    def _plan(self) -> "_Plan":
        plan = self._cache.get("plan")
        if plan is None:
            plan = self._cache["plan"] = _Plan(self)
        return plan

    def _values(self, q: np.ndarray, xi: np.ndarray) -> np.ndarray:
        """Factor values ``(F, m)`` for joint coordinates ``q (m, n)``."""
        plan = self._plan()
        vals = np.empty((len(self.factors), q.shape[0]))
        vals[:] = (plan.const + plan.coef @ xi)[:, None]
        vals[plan.joint_factors] += q[:, plan.joint_of].T
        return vals

    def _sweep(self, qm: np.ndarray, xi: np.ndarray, *, whole: bool = False, tau=None,
               columns: bool = True):
        """Forward kinematics of all poses at once, one step per factor.

        A frame is kept as its three axes and its origin, each ``(3, m)`` (the
        poses contiguous); a factor moves the origin along one axis or turns
        the two others about it, so a step is a few vector operations whatever
        the number of poses, and the axes a factor leaves alone are shared,
        not copied. Returns ``(axes, origin, dp, w, o)``: the tool frame's axes
        (three ``(3, m)``) and origin; ``dp (F, m, 3)``, in the plan's factor
        order (translations first), with each translation's axis (the tool's
        displacement per unit value; the rotations' rows are filled by
        :meth:`_columns`); ``w (R, m, 3)`` each rotation's axis and ``o (R, m,
        3)`` the origin of the frame it acts in (``columns`` False: None each, not
        made: the frames alone, as :meth:`fk` needs them). With ``whole`` also the
        four columns of the frame before every factor."""
        plan = self._plan()
        q = self.joints(qm, xi, tau)
        m = q.shape[0]
        vals = self._values(q, xi)
        rot = vals[plan.rot_factors]
        cos, sin = np.cos(rot), np.sin(rot)
        eye = np.eye(3)
        axes = [np.broadcast_to(eye[:, i, None], (3, m)) for i in range(3)]
        origin = np.zeros((3, m))
        dp = w = o = None
        if columns:
            dp = np.empty((len(self.factors), m, 3))
            w = np.empty((len(plan.rot_factors), m, 3))
            o = np.empty((len(plan.rot_factors), m, 3))
        kept = []
        for j, (t, a, k, slot) in enumerate(plan.steps):
            if whole:
                kept.append((*axes, origin))
            if t:  # T <- T Trans(axis, v): the origin moves along the frame's axis
                if columns:
                    dp[slot] = axes[a].T
                origin = origin + axes[a] * vals[j]
            else:  # T <- T Rot(axis, v): the two other axes turn about it
                if columns:
                    w[k] = axes[a].T
                    o[k] = origin.T
                c, s = cos[k], sin[k]
                b1, b2 = _TURNS[a]
                x, y = axes[b1], axes[b2]
                axes = list(axes)
                axes[b1], axes[b2] = c * x + s * y, c * y - s * x
        out = (axes, origin, dp, w, o)
        return (*out, kept) if whole else out

    @staticmethod
    def _tool(axes, origin) -> np.ndarray:
        m = origin.shape[1]
        T = np.zeros((m, 4, 4))
        for i in range(3):
            T[:, :3, i] = axes[i].T
        T[:, :3, 3] = origin.T
        T[:, 3, 3] = 1.0
        return T

    def frames(self, qm: np.ndarray, xi: np.ndarray, tau=None):
        """Forward kinematics with the intermediate frames.

        Returns ``(T, before)``: ``T (m, 4, 4)`` the tool frame in the base frame,
        and ``before (m, F, 4, 4)`` the frame in which each factor acts (the
        product of all factors before it).
        """
        xi = np.asarray(xi, dtype=float)
        axes, origin, *_cols, kept = self._sweep(qm, xi, whole=True, tau=tau, columns=False)
        m, nf = origin.shape[1], len(self.factors)
        before = np.zeros((m, nf, 4, 4))
        for i in range(4):  # (F, 3, m) -> (m, F, 3)
            before[:, :, :3, i] = np.stack([k[i] for k in kept]).transpose(2, 0, 1)
        before[:, :, 3, 3] = 1.0
        return self._tool(axes, origin), before

    def fk(self, qm: np.ndarray, xi: np.ndarray, tau=None) -> np.ndarray:
        """Tool frames ``(m, 4, 4)`` in the base frame (``tau``: the loads of a chain
        with compliance, ``(m, n)``)."""
        axes, origin, *_cols = self._sweep(qm, np.asarray(xi, dtype=float), tau=tau,
                                           columns=False)
        return self._tool(axes, origin)

    # -- generalized Jacobian ------------------------------------------------
    def factor_columns(self, T: np.ndarray, before: np.ndarray) -> np.ndarray:
        """Spatial columns ``(m, 6, F)``: tool displacement ``[dp; dw]`` per unit
        change of each factor's value (eqs. 16-19)."""
        plan = self._plan()
        nf = before.shape[1]
        u = before[:, np.arange(nf), :3, plan.axis]  # (F, m, 3)
        tr, rt = plan.trans_factors, plan.rot_factors
        cols = np.zeros((before.shape[0], 6, nf))
        cols[:, :3, tr] = u[tr].transpose(1, 2, 0)
        v = T[:, :3, 3] - before[:, :, :3, 3][:, rt].transpose(1, 0, 2)  # (R, m, 3)
        cols[:, :3, rt] = np.cross(u[rt], v).transpose(1, 2, 0)
        cols[:, 3:, rt] = u[rt].transpose(1, 2, 0)
        return cols

    def _columns(self, qm, xi, tau=None):
        """``(T, dp, w)``: tool frames; every factor's position column ``dp``
        (``(F, 3 m)``, plan order, rows (pose, coordinate)): a translation's
        axis, a rotation's ``u x (p_e - o)`` (the tool point turning about the
        axis ``u`` through ``o``); and the rotations' axes ``w`` (``(R, 3 m)``)."""
        axes, origin, dp, w, v = self._sweep(qm, xi, tau=tau)
        nt = len(self._plan().trans_factors)
        np.subtract(origin.T, v, out=v)  # v = p_e - o; u x v, written out
        u0, u1, u2 = w[..., 0], w[..., 1], w[..., 2]
        v0, v1, v2 = v[..., 0], v[..., 1], v[..., 2]
        r = dp[nt:]
        np.multiply(u1, v2, out=r[..., 0])
        r[..., 0] -= u2 * v1
        np.multiply(u2, v0, out=r[..., 1])
        r[..., 1] -= u0 * v2
        np.multiply(u0, v1, out=r[..., 2])
        r[..., 2] -= u1 * v0
        F = dp.shape[0]
        return self._tool(axes, origin), dp.reshape(F, -1), w.reshape(len(w), -1)

    def jacobian(self, qm: np.ndarray, xi: np.ndarray, *, position_only: bool = False,
                 tau=None):
        """Generalized Jacobian by the geometric method.

        Returns ``(T, Psi)``: tool frames ``(m, 4, 4)`` and ``Psi (m, 6, N)``, the
        spatial tool displacement ``[dp; dw]`` (base frame, dw a rotation vector)
        per unit change of each parameter (eq. 24); ``position_only``: only its
        rows ``dp``, ``(m, 3, N)`` (less work, for position measurements). ``tau``:
        the loads of a chain with compliance (a compliance's column is its joint's
        times the load, as a ratio's is times ``Qm``, eq. 23).
        """
        qm = np.atleast_2d(np.asarray(qm, dtype=float))
        xi = np.asarray(xi, dtype=float)
        plan = self._plan()
        T, dp, w = self._columns(qm, xi, tau)
        m = qm.shape[0]
        nt = len(plan.trans_factors)
        # each parameter's column: its factors' columns times their
        # coefficients, plus its joint's (offsets): one matrix product
        parts = [(dp, plan.to_params, plan.to_joints)]
        if not position_only:  # dw: only rotations turn the tool
            parts.append((w, plan.to_params[nt:], plan.to_joints[nt:]))
        psis = []
        for cols, to_params, to_joints in parts:
            psi = (cols.T @ to_params).reshape(m, 3, -1)
            comp = plan.comp_params.size and tau is not None
            if plan.gain_params.size or comp:
                jac_q = (cols.T @ to_joints).reshape(m, 3, -1)
            if plan.gain_params.size:  # eq. 23: Psi_k = Psi_q * Qm[i]
                psi[:, :, plan.gain_params] += jac_q[:, :, plan.gain_joints] * \
                    qm[:, None, plan.gain_joints]
            if comp:                   # Psi_c = Psi_q * tau[i]
                tq = np.atleast_2d(np.asarray(tau, dtype=float))
                psi[:, :, plan.comp_params] += jac_q[:, :, plan.comp_joints] * \
                    tq[:, None, plan.comp_joints]
            psis.append(psi)
        return T, psis[0] if position_only else np.concatenate(psis, axis=1)

    def joint_jacobian(self, qm: np.ndarray, xi: np.ndarray, tau=None) -> np.ndarray:
        """Kinematic Jacobian ``J(Q) (m, 6, n)``: tool displacement per joint coordinate."""
        qm = np.atleast_2d(np.asarray(qm, dtype=float))
        plan = self._plan()
        _T, dp, w = self._columns(qm, np.asarray(xi, dtype=float), tau)
        m, nt = qm.shape[0], len(plan.trans_factors)
        return np.concatenate([(dp.T @ plan.to_joints).reshape(m, 3, -1),
                               (w.T @ plan.to_joints[nt:]).reshape(m, 3, -1)], axis=1)


# For a rotation about axis a, the two axes that turn: (first, second) with
# first' = c first + s second, second' = c second - s first.
_TURNS = {2: (0, 1), 0: (1, 2), 1: (2, 0)}
_AXIS = {"x": 0, "y": 1, "z": 2}


class _Plan:
    """A chain compiled for evaluation (cached per chain): the factors' values
    as ``const + coef @ xi`` plus joint coordinates, the per-factor steps of the
    forward kinematics, and the matrices that map factor columns to parameter
    and joint columns of the Jacobian."""

    def __init__(self, chain: Chain):
        fs, N, n = chain.factors, chain.n_params, chain.n_joints
        F = len(fs)
        self.const = np.array([f.const for f in fs], dtype=float)
        self.coef = np.zeros((F, N))
        to_joints = np.zeros((F, n))
        for j, f in enumerate(fs):
            for i, c in f.terms:
                self.coef[j, i] += c
            if f.joint is not None:
                to_joints[j, f.joint] = 1.0
        self.joint_factors = np.array([j for j, f in enumerate(fs) if f.joint is not None],
                                      dtype=np.intp)
        self.joint_of = np.array([f.joint for f in fs if f.joint is not None], dtype=np.intp)
        self.axis = np.array([_AXIS[f.kind[1]] for f in fs], dtype=np.intp)
        is_rot = [f.kind[0] == "r" for f in fs]
        self.rot_factors = np.flatnonzero(is_rot)
        self.trans_factors = np.flatnonzero(np.logical_not(is_rot))
        rank = np.cumsum(is_rot) - 1
        nt = len(self.trans_factors)
        # the Jacobian's factor columns are kept translations first, then
        # rotations (slot); each step: translation?, axis, rotation rank, slot
        self.steps = tuple((not r, int(a), int(k), int(nt + k if r else j - k - 1))
                           for j, (r, a, k) in enumerate(zip(is_rot, self.axis, rank)))
        order = np.r_[self.trans_factors, self.rot_factors]
        # Psi = cols @ (coef + offsets) + (cols @ to_joints) * Qm on the gains
        to_params = self.coef.copy()
        for jt, i in enumerate(chain.offset_idx):
            if i >= 0:
                to_params[:, i] += to_joints[:, jt]
        self.to_params = to_params[order]
        self.to_joints = to_joints[order]
        gains = [(jt, i) for jt, i in enumerate(chain.gain_idx) if i >= 0]
        self.gain_joints = np.array([jt for jt, _i in gains], dtype=np.intp)
        self.gain_params = np.array([i for _jt, i in gains], dtype=np.intp)
        comps = [(jt, i) for jt, i in enumerate(chain.comp_idx) if i >= 0]
        self.comp_joints = np.array([jt for jt, _i in comps], dtype=np.intp)
        self.comp_params = np.array([i for _jt, i in comps], dtype=np.intp)
        if len(set(self.gain_params.tolist())) < len(gains):
            raise ValueError("two joints share a transmission ratio parameter")
