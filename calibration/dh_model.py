"""A DH chain (report eq. 1, with base and tool compensation, eqs. 3-7) as a
:class:`calibration.chain.Chain`: one link per joint, ``Trans(z,d) Rot(z,theta) Trans(x,a)
Rot(x,alpha)``, its parameters named as the report names them. The tests check the
general chain's Jacobian against it."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calibration.chain import Chain, Factor


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
