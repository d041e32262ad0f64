"""A robot file's arm drawn with matplotlib's mplot3d (the wizard's 3D
picture, :mod:`station.gui.arm3d`, and its plan plot, :mod:`station.gui.plots`, draw with it).

* :func:`stick` gives the stick figure of the model's forward kinematics at
  actuator values: the origin of the frame before every elementary transform of
  the chain (:meth:`calibration.chain.Chain.frames`), so the links follow the
  robot file's DH or Hayati offsets, and the joints where a joint's transform acts;
* :func:`draw_arm` and :func:`draw_floor` draw it, with the floor ``z = 0`` of the
  base frame (where the simulator stops the arm).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from station.gui.pictures import ARM, INK

FLOOR_COLOR = "#8d6e63"


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
    """The stick figure of ``robot`` (a robot file's model) at actuator values ``qm``."""
    chain = robot.chain
    T, before = chain.frames(np.atleast_2d(np.asarray(qm, dtype=float)),
                             np.asarray(xi, dtype=float)[:robot.n_params])
    origins = np.vstack([before[0, :, :3, 3], T[0, :3, 3]])
    joint_factors = [j for j, f in enumerate(chain.factors) if f.joint is not None]
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
