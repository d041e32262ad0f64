"""A serial chain of a URDF robot, from ``base_link`` to ``tip_link`` (docs/urdf-robots.md).

The chain, base to tip::

    T = T_frame * C_1 A_1 D_1 M_1(q_1) A_1^-1 * C_2 A_2 D_2 M_2(q_2) A_2^-1 * ... * C_tail
    T_frame = Trans(base_x, base_y, base_z) Rz(base_yaw) Ry(base_pitch) Rx(base_roll)
              Rx(base_rx) Ry(base_ry) Rz(base_rz)
    D_i     = Trans(x, j{i}_x) Trans(y, j{i}_y) Trans(z, j{i}_z)
              Rot(x, j{i}_rx) Rot(y, j{i}_ry) Rot(z, j{i}_rz)
    M_i     = Rot(z, q_i) (revolute, continuous) or Trans(z, q_i) (prismatic)
    q_i     = k_i * qm_i + q{i}_off                                          (eq. 9)

``C_i`` is the constant transform from the previous movable joint's child frame to
joint i's origin (the fixed joints in between, then joint i's own ``<origin>``),
``A_i`` the constant rotation that turns z onto joint i's ``<axis>``, and ``C_tail``
the fixed joints after the last movable one. ``T_frame`` places the robot's base
link in the measuring instrument's frame (a laser tracker, a motion-capture room):
its orientation ``base_roll, base_pitch, base_yaw`` is an estimate made from the
data and held; the calibration corrects it by the small rotations ``base_rx,
base_ry, base_rz`` about the base link's own axes, so the analysis never meets a
singular angle, whatever the instrument's orientation (``base_x, base_y, base_z``
are the base link's origin in the instrument's frame).

``D_i`` is a correction of joint i's origin in the joint's own frame (z along its
axis), zero at the URDF's values. Every parameter is a candidate; the
identifiability analysis (report section 5) decides which are calibrated. They are
ordered so that the unpivoted QR keeps the instrument frame before the robot's
parameters that it absorbs (the first joints' offsets about or along an axis
parallel to the first joint's, the first joint's origin): the instrument frame,
the offsets ``q{i}_off``, the ratios ``k{i}`` (held at 1: a URDF has no
transmission), then the joints' corrections base to tip.

With ``compliance``, joint i also bends by ``c{i} * tau_i`` (``q_i = k_i * qm_i +
q{i}_off + c{i} * tau_i``), ``tau_i`` gravity's load on it (:func:`gravity_loads`); the
compliances ``c{i}`` follow the ratios in the order.

This module only says how a :class:`UrdfSpec` becomes the parameter layout, the
:class:`calibration.chain.Chain`, the held parameters and the loads
(:data:`URDF_FORM`), and what only a URDF's model offers: its joints' names
(``joint_label``), why a parameter is held (``held_reason``), the calibrated
``<origin>`` of each joint (``calibrated_origins``, what the export writes back) and
the instrument frame (``frame_matrix``). The model of the chain, its kinematics,
Jacobians and inverse kinematics, is :class:`calibration.robots.serial.SerialRobot`
(``UrdfRobot`` is its old name here): generalized coordinates ``[x, y, z, roll, pitch,
yaw]`` of the tip link in the instrument's frame.

Array shapes: ``m`` poses, ``n`` movable joints. Units: metres and radians.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from calibration.chain import Chain, Factor
from calibration.robots.serial import SerialRobot
from calibration.robots.written_form import WrittenForm, transmission_chain

BASE_FREE = ("base_x", "base_y", "base_z", "base_rx", "base_ry", "base_rz")
BASE_HELD = ("base_roll", "base_pitch", "base_yaw")
DELTA_KEYS = ("x", "y", "z", "rx", "ry", "rz")
DELTA_KINDS = ("tx", "ty", "tz", "rx", "ry", "rz")


@dataclass(frozen=True)
class UrdfJoint:
    """One movable joint of the chain (pure data; drivers.urdf_file reads the URDF).

    kind:     ``"R"`` (revolute, continuous) or ``"P"`` (prismatic).
    before:   ``(4, 4)`` constant transform from the previous movable joint's child
              link (the base link for the first) to this joint's origin: the fixed
              joints in between, then this joint's ``<origin>``; nested tuples.
    origin:   ``(4, 4)`` this joint's own ``<origin>`` (what the export rewrites).
    axis:     unit vector of ``<axis>`` in the joint's frame.
    limits:   ``(lower, upper)`` of the joint value (rad or m; continuous: +-pi).
    mass, com: what the joint carries up to the next movable joint, lumped (kg, and its
              centre in the joint's child link frame, m): the load of a compliant model.
    """

    name: str
    kind: str
    before: tuple
    origin: tuple
    axis: tuple[float, float, float]
    limits: tuple[float, float]
    continuous: bool = False
    mass: float = 0.0
    com: tuple[float, float, float] = (0.0, 0.0, 0.0)


@dataclass(frozen=True)
class UrdfSpec:
    """A URDF robot's chain from ``base_link`` to ``tip_link``.

    tail: ``(4, 4)`` the fixed joints after the last movable joint, to the tip link.
    fixed: parameter names held at their start values (default the ratios ``k{i}``
    and the instrument frame's estimated orientation).
    source: ``{name, sha256, text, base_link, tip_link}``: what a trace carries.
    """

    name: str
    base_link: str
    tip_link: str
    joints: tuple[UrdfJoint, ...]
    tail: tuple
    fixed: tuple[str, ...] = ()
    source: dict | None = field(default=None, compare=False)
    compliance: bool = False                  # joints bend under gravity: c{i} parameters
    payload: tuple | None = None              # (mass kg, com (3,) in the tip link frame)

    @property
    def joint_names(self) -> tuple[str, ...]:
        return tuple(j.name for j in self.joints)

    @property
    def form(self) -> WrittenForm:
        return URDF_FORM


def urdf_layout(spec: UrdfSpec) -> list[tuple[str, float]]:
    """``(name, nominal)`` of every parameter, in the model's order (module doc)."""
    n = len(spec.joints)
    out = [(name, 0.0) for name in BASE_FREE[:3]] + [(name, 0.0) for name in BASE_HELD]
    out += [(name, 0.0) for name in BASE_FREE[3:]]
    out += [(f"q{i}_off", 0.0) for i in range(1, n + 1)]
    out += [(f"k{i}", 1.0) for i in range(1, n + 1)]
    if spec.compliance:
        out += [(f"c{i}", 0.0) for i in range(1, n + 1)]
    for i in range(1, n + 1):
        out += [(f"j{i}_{k}", 0.0) for k in DELTA_KEYS]
    return out


def default_fixed(spec: UrdfSpec) -> tuple[str, ...]:
    """Held unless the user frees them: the ratios and the frame's estimated turn."""
    return BASE_HELD + tuple(f"k{i}" for i in range(1, len(spec.joints) + 1))


def held_parameters(spec: UrdfSpec) -> tuple[str, ...]:
    """The spec's ``fixed``, else :func:`default_fixed`."""
    return tuple(spec.fixed) if spec.fixed else default_fixed(spec)


def axis_alignment(axis) -> list[tuple[str, float]]:
    """Rotations ``[(kind, angle), ...]`` whose product turns z onto ``axis``
    (empty for z itself): ``Rz(phi) Ry(theta)``."""
    a = np.asarray(axis, dtype=float)
    a = a / np.linalg.norm(a)
    theta = math.atan2(math.hypot(a[0], a[1]), a[2])
    if theta == 0.0:
        return []
    phi = math.atan2(a[1], a[0])
    return [(k, v) for k, v in (("rz", phi), ("ry", theta)) if v != 0.0]


def rotation_factors(R) -> list[tuple[str, float]]:
    """Elementary rotations ``[(kind, angle), ...]`` whose product is ``R (3, 3)``:
    ``Rz Ry Rx`` (URDF's rpy) where its pitch is well away from +-pi/2, else
    ``Rz Rx Rz`` (well-conditioned exactly there), so the product reproduces ``R``
    to round-off whatever it is."""
    R = np.asarray(R, dtype=float)
    if math.hypot(R[0, 0], R[1, 0]) > 0.3:
        pitch = math.atan2(-R[2, 0], math.hypot(R[0, 0], R[1, 0]))
        out = [("rz", math.atan2(R[1, 0], R[0, 0])), ("ry", pitch),
               ("rx", math.atan2(R[2, 1], R[2, 2]))]
    else:
        out = [("rz", math.atan2(R[0, 2], -R[1, 2])),
               ("rx", math.atan2(math.hypot(R[0, 2], R[1, 2]), R[2, 2])),
               ("rz", math.atan2(R[2, 0], R[2, 1]))]
    return [(k, v) for k, v in out if v != 0.0]


def constant_factors(T) -> list[Factor]:
    """Factors of a constant transform ``T (4, 4)``: its translation, then its rotation."""
    T = np.asarray(T, dtype=float)
    out = [Factor(k, const=float(v)) for k, v in zip(("tx", "ty", "tz"), T[:3, 3]) if v != 0.0]
    return out + [Factor(k, const=v) for k, v in rotation_factors(T[:3, :3])]


def _rot(kind: str, angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    i = "xyz".index(kind[1])
    R = np.eye(4)
    a, b = [(1, 2), (2, 0), (0, 1)][i]
    R[a, a], R[a, b], R[b, a], R[b, b] = c, -s, s, c
    return R


def rotations_matrix(rots) -> np.ndarray:
    """``(4, 4)`` product of ``[(kind, angle), ...]`` (kinds ``rx``, ``ry``, ``rz``)."""
    T = np.eye(4)
    for k, v in rots:
        T = T @ _rot(k, v)
    return T


def joint_pieces(spec: UrdfSpec):
    """Per movable joint ``(C, A)``: the constant transform before its correction
    (the previous joint's un-alignment, ``before``, the alignment) and the alignment
    itself, each ``(4, 4)``; and the tail after the last joint's motion."""
    pieces, undo = [], np.eye(4)
    for jt in spec.joints:
        A = rotations_matrix(axis_alignment(jt.axis))
        pieces.append((undo @ np.asarray(jt.before, dtype=float) @ A, A))
        undo = A.T
    return pieces, undo @ np.asarray(spec.tail, dtype=float)


def build_urdf_chain(spec: UrdfSpec, names: tuple[str, ...]) -> Chain:
    """The factors of the chain (module doc) over the parameters ``names``."""
    ix = {n: j for j, n in enumerate(names)}

    def p(name, kind):
        return Factor(kind, terms=((ix[name], 1.0),))

    factors = [p("base_x", "tx"), p("base_y", "ty"), p("base_z", "tz"),
               p("base_yaw", "rz"), p("base_pitch", "ry"), p("base_roll", "rx"),
               p("base_rx", "rx"), p("base_ry", "ry"), p("base_rz", "rz")]
    pieces, tail = joint_pieces(spec)
    for i, (jt, (C, _A)) in enumerate(zip(spec.joints, pieces), start=1):
        factors += constant_factors(C)
        factors += [p(f"j{i}_{k}", kd) for k, kd in zip(DELTA_KEYS, DELTA_KINDS)]
        factors.append(Factor("rz" if jt.kind == "R" else "tz", joint=i - 1))
    factors += constant_factors(tail)
    return transmission_chain(factors, names, len(spec.joints), spec.compliance)


# -- compliance ----------------------------------------------------------------------
GRAVITY = 9.80665


def gravity_loads(robot, qm):
    """Gravity's torque about each joint's axis (N m; a prismatic joint: the force along
    it, N) at ``qm (m, n)``, from what each joint carries (:class:`UrdfJoint`
    ``mass``, ``com``; the payload on the tip), with the chain at its URDF geometry
    and gravity along the base link's -z; None without compliance. The model bends
    joint i by ``c{i} * tau_i``. The last poses' loads are kept on the model."""
    if not robot.spec.compliance:
        return None
    qm = np.atleast_2d(np.asarray(qm, dtype=float))
    key = (qm.shape, qm.tobytes())
    cache = robot.__dict__.setdefault("_loads_cache", {})
    hit = cache.get("key")
    if hit is not None and hit[0] == key:
        return hit[1]
    tau = _gravity_loads(robot, qm)
    cache["key"] = (key, tau)
    return tau


def _gravity_loads(robot, qm) -> np.ndarray:
    spec, chain = robot.spec, robot.chain
    xi = robot.nominal.copy()              # URDF geometry, base link frame, no bending
    _T, before = chain.frames(qm, xi)
    motion = [j for j, f in enumerate(chain.factors) if f.joint is not None]
    n, m = len(motion), qm.shape[0]
    q = chain.joints(qm, xi)
    axes, origins, coms, masses = [], [], [], []
    pieces, tail = joint_pieces(spec)
    for i, (jt, f) in enumerate(zip(spec.joints, motion)):
        F = before[:, f]                   # the joint's aligned frame (z along its axis)
        M = np.repeat(np.eye(4)[None], m, axis=0)
        if jt.kind == "R":
            c, s_ = np.cos(q[:, i]), np.sin(q[:, i])
            M[:, 0, 0], M[:, 0, 1], M[:, 1, 0], M[:, 1, 1] = c, -s_, s_, c
        else:
            M[:, 2, 3] = q[:, i]
        A = pieces[i][1]
        child = F @ M @ A.T                # the joint's child link frame
        com = np.asarray(jt.com, dtype=float)
        mass = jt.mass
        if i == n - 1 and spec.payload is not None:
            pm, pc = spec.payload
            p_tail = (np.asarray(tail) @ np.r_[pc, 1.0])[:3]
            total = mass + pm
            com = (mass * com + pm * p_tail) / total if total > 0 else com
            mass = total
        axes.append(F[:, :3, 2])
        origins.append(F[:, :3, 3])
        coms.append(child[:, :3, :3] @ com + child[:, :3, 3])
        masses.append(mass)
    g = np.array([0.0, 0.0, -GRAVITY])
    tau = np.zeros((m, n))
    for i, jt in enumerate(spec.joints):
        if jt.kind == "R":
            for b in range(i, n):
                r = coms[b] - origins[i]
                tau[:, i] += masses[b] * np.einsum("mk,mk->m", axes[i], np.cross(r, g))
        else:
            tau[:, i] = sum(masses[b] for b in range(i, n)) * (axes[i] @ g)
    return tau


# -- what only a URDF's model offers (its methods: URDF_FORM.operations) ----------------
def held_reason(robot, name: str) -> str:
    """Why a held parameter is held (the batch table's label)."""
    if name in BASE_HELD:
        return "the instrument frame's estimated turn; base_rx, base_ry, base_rz correct it"
    if name.startswith("k") and name[1:].isdigit():
        return "a URDF joint has no transmission ratio"
    return "fixed"


def joint_label(robot, i: int) -> str:
    """The URDF's name of joint ``i`` (1-based)."""
    return robot.spec.joints[i - 1].name


def calibrated_origins(robot, xi) -> dict[str, np.ndarray]:
    """Per movable joint (URDF name), its ``<origin>`` ``(4, 4)`` with the
    calibration in it: ``origin * A D Rot(q_off) A^-1`` (the correction and the
    offset moved into the origin, so that the joint's value drives it as before:
    the joint turns by ``q`` about its axis where the model turns by
    ``k q + q_off``; ``k`` must be 1)."""
    xi = np.asarray(xi, dtype=float)
    out = {}
    for i, jt in enumerate(robot.spec.joints, start=1):
        A = rotations_matrix(axis_alignment(jt.axis))
        sub = Chain(tuple(Factor(kd, terms=((robot.index(f"j{i}_{k}"), 1.0),))
                          for k, kd in zip(DELTA_KEYS, DELTA_KINDS)), len(xi), (), ())
        D = sub.fk(np.zeros((1, 0)), xi)[0]
        off = float(xi[robot.index(f"q{i}_off")])
        M = _rot("rz", off) if jt.kind == "R" else np.eye(4)
        if jt.kind == "P":
            M[2, 3] = off
        out[jt.name] = np.asarray(jt.origin, dtype=float) @ A @ D @ M @ A.T
    return out


def frame_matrix(robot, xi) -> np.ndarray:
    """``(4, 4)`` the base link in the instrument's frame (``T_frame``)."""
    sub = Chain(robot.chain.factors[:9], len(xi), (), ())
    return sub.fk(np.zeros((1, 0)), np.asarray(xi, dtype=float))[0]


URDF_FORM = WrittenForm(
    layout=urdf_layout, chain=build_urdf_chain, held=held_parameters, loads=gravity_loads,
    operations={"held_reason": held_reason, "joint_label": joint_label,
                "calibrated_origins": calibrated_origins, "frame_matrix": frame_matrix})

#: the model of a URDF's chain is the one serial-chain model (old name; pickles)
UrdfRobot = SerialRobot
