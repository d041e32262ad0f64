"""A robot file's serial chain: DH/Hayati joints (report section 2; docs/robot-files.md).

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
reported dependent. The file's ``fixed`` names are held.

This module only says how a :class:`SerialSpec` becomes the parameter layout and the
:class:`calibration.chain.Chain` (:data:`DH_FORM`); the model of the chain, its
kinematics, Jacobians and inverse kinematics, is :class:`calibration.robots.serial.SerialRobot`.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

from calibration.chain import Chain, Factor
from calibration.robots.written_form import WrittenForm, transmission_chain

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

    @property
    def form(self) -> WrittenForm:
        return DH_FORM


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
    """The factors of eqs. 1-9 (module doc) over the parameters ``names``."""
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
    return transmission_chain(factors, names, len(spec.joints))


def dh_warnings(robot, xi, tol: float = 0.05) -> tuple[str, ...]:
    """Conditioning warnings of the DH form: an R joint in DH form (its ``d`` not
    fixed) whose axis is (nearly) parallel to the next joint's (``|sin alpha_i| < tol``) has an
    ill-defined ``d`` (its common normal slides along the axes): a small
    misalignment needs a huge ``d`` and the fit is ill-conditioned."""
    out = []
    n = len(robot.spec.joints)
    for i, jt in enumerate(robot.spec.joints[:-1], start=1):
        if jt.kind == "R" and not jt.hayati and f"d{i}" not in robot.fixed:
            alpha = float(xi[robot.index(f"alpha{i}")])
            if abs(math.sin(alpha)) < tol and i < n:
                out.append(f"joints {i} and {i + 1} of {robot.name} have (nearly) parallel axes "
                           f"(alpha{i} = {alpha:.4g} rad) and joint {i} is in DH form: d{i} "
                           f"is ill-conditioned there (a small misalignment needs a huge "
                           f"d); give joint {i} Hayati's beta instead of d")
    return tuple(out)


DH_FORM = WrittenForm(layout=param_layout, chain=build_chain, warnings=dh_warnings)
