"""A robot file's arm drawn with matplotlib's mplot3d (the wizard's 3D
picture, :mod:`station.gui.arm3d`, and its plan plot, :mod:`station.gui.plots`, draw with it).

* :func:`stick` gives the stick figure of the model's forward kinematics at
  actuator values: the origin of the frame before every elementary transform of
  the chain (:meth:`calibration.chain.Chain.frames`), so the links follow the
  robot file's DH or Hayati offsets, and the joints where a joint's transform acts;
  a URDF robot's (:func:`is_urdf`) goes from its base link through its joints' origins
  to the tip link (its constant transforms are a joint's ``<origin>`` in x, y, z steps:
  the links are drawn straight from joint to joint);
* :func:`draw_arm` and :func:`draw_floor` draw it, with the floor ``z = 0`` of the
  base frame (where the simulator stops the arm);
* a URDF robot measured by a point instrument (sm-markers) is drawn in its base link's
  frame (:func:`base_frame`: the instrument frame left out), the points on its tool
  where an estimate puts them (:func:`tool_points`) and the instrument's readings
  brought into that frame (:func:`to_base`), :func:`draw_points`.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from station.gui.pictures import ARM, INK, MARKER_EST, MARKER_SEEN

FLOOR_COLOR = "#8d6e63"
#: the parameters that place a URDF robot's base link in the instrument's frame
FRAME_PARAMS = ("base_x", "base_y", "base_z", "base_roll", "base_pitch", "base_yaw",
                "base_rx", "base_ry", "base_rz")


def is_urdf(robot) -> bool:
    """Whether ``robot`` is a URDF robot's model (its chain from a base link to a tip link)."""
    return hasattr(getattr(robot, "spec", None), "base_link")


def base_frame(robot, xi) -> np.ndarray:
    """``xi`` with a URDF robot's instrument frame left out (:data:`FRAME_PARAMS` zero):
    its chain in its base link's frame; another robot's ``xi`` as it is."""
    xi = np.array(xi, dtype=float)[:robot.n_params]
    if is_urdf(robot):
        for name in FRAME_PARAMS:
            xi[robot.index(name)] = 0.0
    return xi


@dataclass(frozen=True)
class Stick:
    """The arm at one pose (m, base frame): ``points`` the polyline base -> tool through
    the origin of every transform's frame; ``first`` the index of the first joint's
    frame in it (before it: the base transform); ``joints`` the joints' origins;
    ``tool`` the tool frame (4x4)."""

    points: np.ndarray
    first: int
    joints: np.ndarray
    tool: np.ndarray


def stick(robot, qm, xi) -> Stick:
    """The stick figure of ``robot`` (a robot file's or a URDF robot's model) at actuator
    values ``qm``."""
    chain = robot.chain
    T, before = chain.frames(np.atleast_2d(np.asarray(qm, dtype=float)),
                             np.asarray(xi, dtype=float)[:robot.n_params])
    joint_factors = [j for j, f in enumerate(chain.factors) if f.joint is not None]
    if is_urdf(robot):      # the base link, the joints' origins, the tip link
        base = len(FRAME_PARAMS)        # the frame's factors come first
        origins = np.vstack([before[0, [base] + joint_factors, :3, 3], T[0, :3, 3]])
        keep = [0] + [k for k in range(1, len(origins))
                      if np.linalg.norm(origins[k] - origins[k - 1]) > 1e-9]
        return Stick(origins[keep], 0, before[0, joint_factors, :3, 3], T[0])
    origins = np.vstack([before[0, :, :3, 3], T[0, :3, 3]])
    keep = [0] + [k for k in range(1, len(origins))
                  if np.linalg.norm(origins[k] - origins[k - 1]) > 1e-9]
    k0 = joint_factors[0] if joint_factors else 0   # a dropped point repeats the one before
    first = max(i for i, k in enumerate(keep) if k <= k0)
    return Stick(origins[keep], first, before[0, joint_factors, :3, 3], T[0])


def view_box(robot, xi, qm) -> tuple[np.ndarray, np.ndarray]:
    """``(lo, hi)`` (m) of the box the picture shows: most (5 to 95 %) of the tool origins
    of random poses in the middle of the joint limits above the floor (the planned
    workspace, :func:`station.planning.serial_plan.safe_pool`) and of the arm at ``qm``, the
    first joint, with a margin; from just below the floor ``z = 0`` up (the arm stops
    at the floor)."""
    from station.planning.serial_plan import safe_pool

    xi = np.asarray(xi, dtype=float)[:robot.n_params]
    s = stick(robot, qm, xi)
    try:
        pool = safe_pool(robot, xi, np.random.default_rng(0), count=300)
        pts = np.vstack([robot.frames(pool, xi)[:, :3, 3], s.points[s.first:]])
    except Exception:  # noqa: BLE001 - no safe pose drawn: the arm alone
        pts = s.points[s.first:]
    lo, hi = np.percentile(pts, 5, axis=0), np.percentile(pts, 95, axis=0)
    lo, hi = np.minimum(lo, s.points[s.first]), np.maximum(hi, s.points[s.first])
    pad = 0.05 * float(np.max(hi - lo)) + 0.03
    lo, hi = lo - pad, hi + pad
    lo[2] = -0.02
    return lo, hi


def draw_floor(ax, lo, hi, scale: float) -> None:
    """The floor ``z = 0`` of the base frame over the box ``lo..hi`` (m)."""
    xs = np.array([lo[0], hi[0]]) * scale
    ys = np.array([lo[1], hi[1]]) * scale
    X, Y = np.meshgrid(xs, ys)
    ax.plot_surface(X, Y, np.zeros_like(X), color=FLOOR_COLOR, alpha=0.12, linewidth=0,
                    shade=False)
    ax.plot([xs[0], xs[1], xs[1], xs[0], xs[0]], [ys[0], ys[0], ys[1], ys[1], ys[0]],
            [0] * 5, color=FLOOR_COLOR, lw=0.8, alpha=0.6)
    ax.text(xs[0], ys[0], 0.0, " floor z = 0", color=FLOOR_COLOR, fontsize=7)


def draw_arm(ax, s: Stick, scale: float, *, color: str = ARM, alpha: float = 1.0,
             lw: float = 4.0, label: str | None = None) -> None:
    """The arm ``s``: its links, joints (white discs) and tool origin (a dark dot); the
    base transform (base frame to the first joint) thin and dashed."""
    P = s.points * scale
    if s.first > 0:
        B = P[:s.first + 1]
        ax.plot(B[:, 0], B[:, 1], B[:, 2], color="#999", lw=0.8, ls=":", alpha=alpha)
    A = P[s.first:]
    ax.plot(A[:, 0], A[:, 1], A[:, 2], color=color, lw=lw, alpha=alpha,
            solid_capstyle="round", label=label)
    J = s.joints * scale
    ax.scatter(J[:, 0], J[:, 1], J[:, 2], s=26, color="white", edgecolors=INK,
               linewidths=1.0, alpha=alpha, depthshade=False)
    t = s.tool[:3, 3] * scale
    ax.scatter([t[0]], [t[1]], [t[2]], s=22, color=INK, alpha=alpha, depthshade=False)


def setup_axes(ax, lo, hi, scale: float, unit: str) -> None:
    ax.set_xlim(lo[0] * scale, hi[0] * scale)
    ax.set_ylim(lo[1] * scale, hi[1] * scale)
    ax.set_zlim(lo[2] * scale, hi[2] * scale)
    ax.set_box_aspect(tuple(hi - lo), zoom=1.0)      # room for the z label at the side
    for setter, name in zip((ax.set_xlabel, ax.set_ylabel, ax.set_zlabel), "xyz"):
        setter(f"{name} [{unit}]", fontsize=7, labelpad=0)
    ax.tick_params(labelsize=6, pad=0)


def tool_points(tool: np.ndarray, points) -> np.ndarray:
    """``(M, 3)`` the points ``points`` ``(M, 3)`` (m, the tip link's frame) with the tool
    at ``tool`` (4x4)."""
    P = np.asarray(points, dtype=float).reshape(-1, 3)
    return P @ tool[:3, :3].T + tool[:3, 3]


def to_base(frame: np.ndarray, readings) -> np.ndarray:
    """``(M, 3)`` the instrument's readings ``(M, 3)`` (its frame; NaN: not seen) in the base
    link's frame, ``frame`` (4x4) the base link in the instrument's frame."""
    P = np.asarray(readings, dtype=float).reshape(-1, 3)
    R, t = frame[:3, :3], frame[:3, 3]
    return (P - t) @ R


def draw_points(ax, estimated, measured, scale: float) -> None:
    """The points on the tool: ``estimated`` ``(M, 3)`` (where the estimate puts them,
    hollow rings) and ``measured`` ``(M, 3)`` (read now, dots; a NaN row is a point not
    seen, not drawn); either may be None. One caption beside them (a few centimetres
    apart, each point's own would cover the others'; the picture's lines name them)."""
    where = None
    if estimated is not None:
        E = np.asarray(estimated, dtype=float) * scale
        ax.scatter(E[:, 0], E[:, 1], E[:, 2], s=70, facecolors="none", edgecolors=MARKER_EST,
                   linewidths=1.6, depthshade=False)
        where = E.max(axis=0)
    if measured is not None:
        M = np.asarray(measured, dtype=float) * scale
        seen = np.all(np.isfinite(M), axis=1)
        if seen.any():
            ax.scatter(M[seen, 0], M[seen, 1], M[seen, 2], s=24, color=MARKER_SEEN,
                       depthshade=False)
            where = M[seen].max(axis=0) if where is None else np.maximum(where,
                                                                         M[seen].max(axis=0))
    if where is not None:
        ax.text(where[0], where[1], where[2], "  markers", color=MARKER_SEEN, fontsize=7)
