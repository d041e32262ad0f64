"""sm-markers: points fixed on the tool (a laser tracker's reflectors, a motion
capture's markers) measured in the instrument's own frame (docs/urdf-robots.md).

Channel ``markers``: per pose ``(M, 3)`` positions, m, NaN where a point was not
seen. The instrument's frame is the robot's base compensation (a URDF robot's
``base_*``: its orientation estimated from the data and held, corrected by small
rotations about the base link's axes); each point's position on the tool is a
parameter ``marker{j}_x, _y, _z`` of the method, in the tip link's frame.

Residual ``p_M - (p_e + R_e u_j)`` for every seen point, rows ``(pose, point, x y z)``;
observation matrix: the tool's displacement at the point, ``dp + dw x (R_e u_j)``
(eqs. 16-24), and ``R_e`` for the point's own position. The three rows of a point
share one channel (one sigma), and the statistics that judge a point (outliers,
held-out errors) take its three rows together, so nothing depends on how the
instrument's frame is turned.

:func:`register` gives start values: the instrument's frame and the points on the
tool that best explain the readings with the robot at its start values (Kabsch's
rotation and a linear least-squares fit of the translation and the points,
alternated), from which Algorithm 2 starts.
"""
from __future__ import annotations

import math

import numpy as np

from calibration.errors import CalibrationError
from calibration.methods.base import RobotMethod

AXES = ("x", "y", "z")
#: poses evaluated together (:meth:`Markers.evaluate`)
POSE_BLOCK = 4096


def marker_names(count: int) -> tuple[str, ...]:
    return tuple(f"marker{j}_{a}" for j in range(1, count + 1) for a in AXES)


def marker_count(names) -> int:
    """How many points a parameter list holds (``marker{j}_x ...``)."""
    return sum(1 for n in names if n.startswith("marker") and n.endswith("_x"))


def points_array(value, count: int | None = None) -> np.ndarray:
    """``(m, M, 3)`` from the trace's per-pose lists of ``[x, y, z]`` or None."""
    rows = []
    for pose in value:
        rows.append([[math.nan] * 3 if p is None else p for p in pose])
    a = np.asarray(rows, dtype=float)
    if a.ndim != 3 or a.shape[2] != 3 or (count is not None and a.shape[1] != count):
        raise CalibrationError(f"channel 'markers' must hold {count or 'M'} points [x, y, z] "
                               f"per pose, got shape {a.shape}")
    return a


class Markers(RobotMethod):
    method = "sm-markers"
    default_damping = 1e-4

    def __init__(self, robot, qm, measured: dict, nominal):
        if "markers" not in measured:
            raise CalibrationError("method sm-markers needs the measured channel 'markers'")
        if not hasattr(robot, "frame_matrix"):
            raise CalibrationError(f"method sm-markers takes a URDF robot (--robot FILE.urdf "
                                   f"--base-link B --tip-link T); {robot.name} is not one")
        pts = np.asarray(measured["markers"], dtype=float)
        if pts.ndim != 3 or pts.shape[2] != 3:
            raise CalibrationError(f"channel 'markers' must have shape (poses, points, 3), "
                                   f"got {pts.shape}")
        self.n_markers = pts.shape[1]
        self.extra_names = marker_names(self.n_markers)
        super().__init__(robot, qm, nominal)
        seen = np.all(np.isfinite(pts), axis=2)
        if np.any(np.isfinite(pts).any(axis=2) & ~seen):
            bad = np.argwhere(np.isfinite(pts).any(axis=2) & ~seen)[0]
            raise CalibrationError(f"point {int(bad[1]) + 1} of pose {int(bad[0])} has a "
                                   f"coordinate missing (x, y and z are seen together)")
        if not seen.any(axis=1).all():
            i = int(np.flatnonzero(~seen.any(axis=1))[0])
            raise CalibrationError(f"pose {i} sees no point")
        self.points, self.seen = pts, seen
        self.pose_of, self.marker_of = np.nonzero(seen)
        rows = 3 * len(self.pose_of)
        self._channels(("marker",), [0, 0, 0])
        self.row_channel = np.zeros(rows, dtype=np.intp)
        self.row_pose = np.repeat(self.pose_of, 3)          # pose (position) of each row
        self.row_group = np.repeat(np.arange(len(self.pose_of)), 3)  # one point: 3 rows
        self.group_size = 3
        # the instrument's frame, then the points on the tool, then the robot: what
        # an unknown frame or tool absorbs (the first joints' offsets about a vertical
        # axis, the last joint's offset and its origin along its axis) is theirs
        base = [j for j, n in enumerate(self.names[:self.nr]) if n.startswith("base_")]
        rest = [j for j in range(self.nr) if j not in base]
        self.identify_order = np.array(base + list(range(self.nr, len(self.names))) + rest)

    def predict(self, x):
        """``(points (m, M, 3), T (m, 4, 4), psi (m, 6, N_robot))`` at ``x`` (made
        :data:`POSE_BLOCK` poses at a time: the chain's temporaries stay small)."""
        m = len(self.qm)
        xr = np.asarray(x)[:self.nr]
        if m <= POSE_BLOCK:
            T, psi = self.robot.spatial_jacobian(self.qm, xr)
        else:
            T = psi = None
            for lo in range(0, m, POSE_BLOCK):
                hi = min(lo + POSE_BLOCK, m)
                Tb, pb = self.robot.spatial_jacobian(self.qm[lo:hi], xr)
                if T is None:
                    T, psi = np.empty((m,) + Tb.shape[1:]), np.empty((m,) + pb.shape[1:])
                T[lo:hi], psi[lo:hi] = Tb, pb
        u = np.asarray(x[self.nr:], dtype=float).reshape(self.n_markers, 3)
        arm = np.einsum("mij,kj->mki", T[:, :3, :3], u)       # R_e u_j
        return T[:, None, :3, 3] + arm, T, psi, arm

    def evaluate(self, x):
        """Residuals and Jacobian, :data:`POSE_BLOCK` poses at a time (a block's
        temporaries, the tip frames and their screws, stay small however many poses:
        100 000 poses of three points are a 900 000-row matrix, and its temporaries
        were four times its size)."""
        x = np.asarray(x, dtype=float)
        s, n = len(self.pose_of), self.nr + 3 * self.n_markers
        m = len(self.qm)
        if m <= POSE_BLOCK:
            return self._rows(x, 0, m, 0, s)
        r = np.empty(3 * s)
        W = np.empty((3 * s, n))
        ends = np.searchsorted(self.pose_of, np.arange(0, m + POSE_BLOCK, POSE_BLOCK)[1:])
        lo_s = 0
        for b, hi_s in enumerate(ends.tolist()):
            lo = b * POSE_BLOCK
            # (the block's rows of W written in place: no block-sized copy on the way)
            r[3 * lo_s:3 * hi_s] = self._rows(x, lo, min(lo + POSE_BLOCK, m), lo_s, hi_s,
                                              out=W[3 * lo_s:3 * hi_s])[0]
            lo_s = hi_s
        return r, W

    def _rows(self, x, lo: int, hi: int, lo_s: int, hi_s: int, out=None):
        """The rows of poses ``lo:hi``, whose seen points are ``lo_s:hi_s`` (their rows
        of W written into ``out`` where given)."""
        T, psi = self.robot.spatial_jacobian(self.qm[lo:hi], x[:self.nr])
        u = x[self.nr:].reshape(self.n_markers, 3)
        arm = np.einsum("mij,kj->mki", T[:, :3, :3], u)       # R_e u_j
        pred = T[:, None, :3, 3] + arm
        i, k = self.pose_of[lo_s:hi_s] - lo, self.marker_of[lo_s:hi_s]
        r = (self.points[i + lo, k] - pred[i, k]).reshape(-1)
        dp, dw = psi[i, :3, :], psi[i, 3:, :]                    # (s, 3, Nr)
        a = arm[i, k]                                             # (s, 3)
        cross = np.stack([dw[:, 1] * a[:, 2, None] - dw[:, 2] * a[:, 1, None],
                          dw[:, 2] * a[:, 0, None] - dw[:, 0] * a[:, 2, None],
                          dw[:, 0] * a[:, 1, None] - dw[:, 1] * a[:, 0, None]], axis=1)
        s = len(i)
        if out is None:
            W = np.zeros((s, 3, self.nr + 3 * self.n_markers))
        else:
            W = out.reshape(s, 3, -1)
            W[:, :, self.nr:] = 0.0
        W[:, :, :self.nr] = dp + cross
        cols = self.nr + 3 * k[:, None] + np.arange(3)            # (s, 3)
        W[np.arange(s)[:, None, None], np.arange(3)[None, :, None], cols[:, None, :]] = \
            T[i, :3, :3]
        return r, W.reshape(3 * s, -1)

    def measured_points(self) -> np.ndarray:
        """The seen points ``(s, 3)``, in the residual's row order."""
        return self.points[self.pose_of, self.marker_of]

    def point_errors(self, r) -> np.ndarray:
        """3D distance of each seen point from its prediction, from the residual ``r``."""
        return np.linalg.norm(np.asarray(r, dtype=float).reshape(-1, 3), axis=1)


def _kabsch(A: np.ndarray, B: np.ndarray):
    """Rotation ``R`` and translation ``t`` with ``B ~ R A + t`` (least squares, a proper
    rotation), and the same with a reflection allowed (``det = -1``): ``(R, t, R_any,
    t_any)``; ``A, B (s, 3)``."""
    ca, cb = A.mean(axis=0), B.mean(axis=0)
    H = (A - ca).T @ (B - cb)
    U, _s, Vt = np.linalg.svd(H)
    d = np.sign(np.linalg.det(Vt.T @ U.T)) or 1.0
    R = Vt.T @ np.diag([1.0, 1.0, d]) @ U.T
    R_any = Vt.T @ U.T
    return R, cb - R @ ca, R_any, cb - R_any @ ca


#: the instrument frame's parameters (the base link placed in the instrument's frame)
FRAME_PARAMS = ("base_x", "base_y", "base_z", "base_rx", "base_ry", "base_rz",
                "base_roll", "base_pitch", "base_yaw")


def tip_frames(robot, qm, xi) -> np.ndarray:
    """``(m, 4, 4)`` the tip link's frames in the base link's frame for the robot at
    ``xi`` (its own parameters; the instrument frame's, :data:`FRAME_PARAMS`, left out)."""
    xi = np.array(xi, dtype=float)
    xi[[robot.index(name) for name in FRAME_PARAMS]] = 0.0
    return robot.frames(qm, xi)


def register(robot, qm, points, xi, *, iterations: int = 200, tol: float = 1e-12,
             proper: bool = True):
    """Start values of the instrument's frame and the points on the tool for the robot
    at ``xi`` (its own parameters; the base's are replaced).

    Returns ``(R, t, u, median)``: the base link's orientation ``R (3, 3)`` and origin
    ``t (3,)`` in the instrument's frame, the points ``u (M, 3)`` in the tip link's
    frame, and the median 3D distance of the readings from their prediction (robust
    to a few gross readings, which the fit-quality gate judges). ``proper``
    False lets the placement mirror (``det R = -1``; :func:`mirror_check`)."""
    T = tip_frames(robot, qm, xi)
    Rt, pt = T[:, :3, :3], T[:, :3, 3]
    pts = np.asarray(points, dtype=float)
    seen = np.all(np.isfinite(pts), axis=2)
    i, k = np.nonzero(seen)
    M = pts.shape[1]
    u = np.zeros((M, 3))
    B = pts[i, k]
    # where each point is on the tool, seen from the tip: start at the tip's origin
    R, t = np.eye(3), np.zeros(3)
    prev = math.inf
    for _ in range(iterations):
        A = pt[i] + np.einsum("sij,sj->si", Rt[i], u[k])
        R, t = _kabsch(A, B)[:2] if proper else _kabsch(A, B)[2:]
        # given R: B - R p_e = t + R R_e u_k, linear in (t, u)
        G = np.zeros((len(i), 3, 3 + 3 * M))
        G[:, :, :3] = np.eye(3)
        RR = np.einsum("ij,sjk->sik", R, Rt[i])
        G[np.arange(len(i))[:, None, None], np.arange(3)[None, :, None],
          (3 + 3 * k[:, None] + np.arange(3))[:, None, :]] = RR
        rhs = (B - pt[i] @ R.T).reshape(-1)
        sol = np.linalg.lstsq(G.reshape(-1, 3 + 3 * M), rhs, rcond=None)[0]
        t, u = sol[:3], sol[3:].reshape(M, 3)
        res = rhs - G.reshape(-1, 3 + 3 * M) @ sol
        cost = float(res @ res)
        if prev - cost <= tol * max(prev, 1e-300) and math.isfinite(prev):
            break
        prev = cost
    dist = np.linalg.norm(res.reshape(-1, 3), axis=1)
    return R, t, u, float(np.median(dist)) if dist.size else 0.0


def scale_and_mirror(robot, qm, points, xi) -> tuple[float, float, float]:
    """What a person checks first, with the robot at ``xi``: ``(scale, proper, mirrored)``.

    scale: how far the points move against how far the tip does (the similarity
    transform's scale, Umeyama, between the tip's origins and each pose's mean
    point): about 1 where lengths and angles are in the right units, 1000 for mm
    read as m. proper, mirrored: the 3D RMS of the readings from their prediction
    under the best proper placement (:func:`register`) and the best one allowed to
    mirror; a mirrored frame (an axis sign-flipped or two swapped in the
    instrument's export, which no rotation gives) fits the second far better (both
    median distances)."""
    xi = np.array(xi, dtype=float)
    T = robot.frames(qm, xi)
    pts = np.asarray(points, dtype=float)
    seen = np.all(np.isfinite(pts), axis=2)
    mean = np.array([pts[i][seen[i]].mean(axis=0) for i in range(len(pts))])
    A = T[:, :3, 3] - T[:, :3, 3].mean(axis=0)
    B = mean - mean.mean(axis=0)
    var = float(np.sum(A * A))
    scale = float(np.linalg.svd(A.T @ B, compute_uv=False).sum() / var) if var > 0 else math.inf
    return (scale, register(robot, qm, pts, xi)[3],
            register(robot, qm, pts, xi, proper=False)[3])
