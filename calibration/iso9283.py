"""Pose accuracy and pose repeatability as ISO 9283:1998 defines them (its sections 6 and
7.2): the test cube, its five measuring points, and AP and RP of n attained poses.

**The cube and its points.** The test cube has its edges parallel to the axes of a frame
``R`` (the standard: the robot's base frame, ``R = I``), its centre ``c`` and its edge
``size``. Its corners, numbered here (``R``'s axes, half an edge ``h``)::

    C1 (-h, -h, -h)   C2 (+h, -h, -h)   C3 (+h, +h, -h)   C4 (-h, +h, -h)
    C5 (-h, -h, +h)   C6 (+h, -h, +h)   C7 (+h, +h, +h)   C8 (-h, +h, +h)

(C5..C8 above C1..C4). The measuring plane is the diagonal plane C1-C2-C7-C8 (it holds
the lower edge C1-C2 and the upper edge C7-C8); on it, P1 is the centre of the cube (the
diagonals' intersection) and P2, P3, P4, P5 lie on the diagonals at 10 % of the
diagonal's length from the corners C1, C2, C7, C8 (``P = c + 0.8 (C - c)``; the
diagonal is the cube's space diagonal, ``size * sqrt(3)``). A cycle visits
P1, P5, P4, P3, P2 (:data:`CYCLE`), each pose approached from the one before it (the
standard's unidirectional approach: a cycle ends at P2, the next starts from there).

**Position.** With ``(x_j, y_j, z_j)`` the ``n`` attained positions of one commanded pose
``(x_c, y_c, z_c)`` and ``(x̄, ȳ, z̄)`` their barycentre:

* pose accuracy ``AP_P = sqrt((x̄ - x_c)² + (ȳ - y_c)² + (z̄ - z_c)²)``, and its
  components ``AP_x = x̄ - x_c``, ``AP_y``, ``AP_z``;
* pose repeatability ``RP_l = l̄ + 3 S_l``, ``l_j`` the distance of the j-th attained
  position from the barycentre, ``l̄`` their mean and
  ``S_l = sqrt(Σ (l_j - l̄)² / (n - 1))``.

**Orientation**, where the instrument gives it: ``a, b, c`` the rotations about the x,
y and z axes; ``AP_a = ā - a_c`` (likewise b, c) and ``RP_a = ±3 S_a``,
``S_a = sqrt(Σ (a_j - ā)² / (n - 1))``. Here each attained orientation is taken as its
small rotation from the commanded one (:func:`deviation_angles`: the rotation vector
about the axes of ``R``), so that ``a_c = b_c = c_c = 0``; for the deviations of a
robot (mrad) this is the difference of the angles the standard writes to within their
square.

Pure numerics: arrays in, numbers out. Units: whatever the positions are in (m here),
radians.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

#: P2..P5 lie this share of the diagonal from the measuring plane's corners
FRACTION = 0.10
#: the standard's number of cycles
CYCLES = 30
#: the measuring points' names and the corners P2..P5 are near (0-based C1..C8)
POINTS = ("P1", "P2", "P3", "P4", "P5")
PLANE_CORNERS = (0, 1, 6, 7)              # C1, C2, C7, C8
#: the order of one cycle
CYCLE = ("P1", "P5", "P4", "P3", "P2")
_SIGNS = np.array([[-1, -1, -1], [1, -1, -1], [1, 1, -1], [-1, 1, -1],
                   [-1, -1, 1], [1, -1, 1], [1, 1, 1], [-1, 1, 1]], dtype=float)


def _axes(R) -> np.ndarray:
    A = np.eye(3) if R is None else np.asarray(R, dtype=float).reshape(3, 3)
    if not np.allclose(A.T @ A, np.eye(3), atol=1e-9) or np.linalg.det(A) < 0:
        raise ValueError("the cube's axes R must be a rotation matrix")
    return A


def cube_corners(centre, size: float, R=None) -> np.ndarray:
    """``(8, 3)`` the corners C1..C8 (module doc) of the cube of edge ``size`` about
    ``centre``, its edges along the columns of ``R`` (default: the frame's axes)."""
    if not (math.isfinite(size) and size > 0):
        raise ValueError(f"a cube's edge is a length > 0, not {size!r}")
    A = _axes(R)
    return np.asarray(centre, dtype=float) + (0.5 * float(size) * _SIGNS) @ A.T


def measuring_points(centre, size: float, R=None, fraction: float = FRACTION) -> np.ndarray:
    """``(5, 3)`` P1..P5 (module doc): the centre, then the points at ``fraction`` of the
    diagonal from C1, C2, C7 and C8."""
    c = np.asarray(centre, dtype=float)
    C = cube_corners(c, size, R)[list(PLANE_CORNERS)]
    return np.vstack([c, c + (1.0 - 2.0 * fraction) * (C - c)])


def accuracy(attained, commanded) -> tuple[float, np.ndarray]:
    """``(AP_P, (AP_x, AP_y, AP_z))`` of ``attained (n, 3)`` positions of one commanded
    position ``(3,)``."""
    P = np.atleast_2d(np.asarray(attained, dtype=float))
    d = P.mean(axis=0) - np.asarray(commanded, dtype=float)
    return float(np.linalg.norm(d)), d


def repeatability(attained) -> tuple[float, float, float]:
    """``(RP_l, l̄, S_l)`` of ``attained (n, 3)`` positions (n >= 2)."""
    P = np.atleast_2d(np.asarray(attained, dtype=float))
    if len(P) < 2:
        raise ValueError("repeatability needs two attained positions at least")
    lj = np.linalg.norm(P - P.mean(axis=0), axis=1)
    lbar = float(lj.mean())
    s = float(np.sqrt(np.sum((lj - lbar) ** 2) / (len(lj) - 1)))
    return lbar + 3.0 * s, lbar, s


def deviation_angles(R_commanded, R_attained, R=None) -> np.ndarray:
    """``(a, b, c)`` rad: the rotation from the commanded orientation to the attained one
    (``R_attained = exp([w]x) R_commanded``, both ``(3, 3)`` in one frame) as a rotation
    vector about the axes of ``R`` (that frame's own by default). Stacks ``(n, 3, 3)``
    attained give ``(n, 3)``."""
    A = _axes(R)
    Ra = np.asarray(R_attained, dtype=float)
    one = Ra.ndim == 2
    E = Ra.reshape(-1, 3, 3) @ np.asarray(R_commanded, dtype=float).T
    v = 0.5 * np.stack([E[:, 2, 1] - E[:, 1, 2], E[:, 0, 2] - E[:, 2, 0],
                        E[:, 1, 0] - E[:, 0, 1]], axis=1)
    s = np.linalg.norm(v, axis=1)
    ang = np.arctan2(s, (np.trace(E, axis1=1, axis2=2) - 1.0) / 2.0)
    w = v * np.where(s > 1e-300, ang / np.where(s > 1e-300, s, 1.0), 1.0)[:, None]
    w = w @ A                               # about R's axes: A^T w
    return w[0] if one else w


def orientation(angles, commanded=(0.0, 0.0, 0.0)) -> tuple[np.ndarray, np.ndarray]:
    """``((AP_a, AP_b, AP_c), (RP_a, RP_b, RP_c))`` of ``angles (n, 3)`` (rad) of one
    commanded orientation ``(a_c, b_c, c_c)``: the mean's difference, and three times
    the sample std (the standard's ``±3 S``; n >= 2)."""
    A = np.atleast_2d(np.asarray(angles, dtype=float))
    if len(A) < 2:
        raise ValueError("repeatability needs two attained orientations at least")
    return A.mean(axis=0) - np.asarray(commanded, dtype=float), 3.0 * A.std(axis=0, ddof=1)


@dataclass(frozen=True)
class PoseResult:
    """AP and RP of one measuring point (module doc; positions' unit, rad).

    name: ``"P1"`` .. ``"P5"``; n: the attained poses it is of; ap, ap_xyz: ``AP_P`` and
    its components; rp, lbar, s_l: ``RP_l``, ``l̄``, ``S_l``; ap_abc, rp_abc: the
    orientation's (None where not measured)."""

    name: str
    n: int
    ap: float
    ap_xyz: tuple
    rp: float
    lbar: float
    s_l: float
    ap_abc: tuple | None = None
    rp_abc: tuple | None = None


def pose_result(name: str, attained, commanded, angles=None) -> PoseResult:
    """The :class:`PoseResult` of ``attained (n, 3)`` positions of ``commanded (3,)`` and,
    where given, the deviation ``angles (n, 3)`` of their orientations
    (:func:`deviation_angles`)."""
    ap, d = accuracy(attained, commanded)
    rp, lbar, s = repeatability(attained)
    ap_abc = rp_abc = None
    if angles is not None:
        a, r = orientation(angles)
        ap_abc, rp_abc = tuple(map(float, a)), tuple(map(float, r))
    return PoseResult(name, len(np.atleast_2d(attained)), ap, tuple(map(float, d)), rp, lbar,
                      s, ap_abc, rp_abc)
