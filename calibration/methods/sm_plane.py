"""sm-plane (report 7.4): the end effector touches an unknown plane
``a x + b y + c z + 1 = 0``; only ``Qm`` is recorded.

The plane parameters ``plane_a, plane_b, plane_c`` are calibrated too (eq. 69);
unless given, they start from the least-squares plane through the nominal
contact points (eq. 74). Rows ``0 - (a x + b y + c z + 1)`` with the
observation row ``[(a, b, c) Psi[1:3], X[1:3]]`` (eq. 73; parameters ordered
robot first, plane last). ``L4, theta0, a0`` and the plane are not identifiable
and influence the model.
"""
from __future__ import annotations

import copy

import numpy as np

from calibration.errors import CalibrationError, UnreachablePose
from calibration.methods.base import RobotMethod

PLANE = ("plane_a", "plane_b", "plane_c")


def plane_through(points: np.ndarray) -> np.ndarray:
    """Eq. 74: ``(a, b, c)`` minimising ``sum (a x + b y + c z + 1)^2``."""
    sol, *_ = np.linalg.lstsq(points, -np.ones(len(points)), rcond=None)
    return sol


class Plane(RobotMethod):
    method = "sm-plane"
    # 1e-2: with 1e-4 Gauss-Newton from the report's nominal can fall into the
    # degenerate "frozen robot" solution (all ratios k -> 0, every contact at one
    # point of the plane), which fits the constraint exactly.
    default_damping = 1e-2
    extra_names = PLANE

    def __init__(self, robot, qm, measured: dict, nominal, *, plane_given: bool = False):
        super().__init__(robot, qm, nominal)
        if not plane_given:
            pts = robot.fk(self.qm, self.nominal[:self.nr])[:, :3]
            if np.linalg.matrix_rank(pts - pts.mean(axis=0), tol=1e-9) < 2:
                raise CalibrationError("the contact points are collinear: they do not span a plane")
            self.x0 = self.nominal.copy()
            self.x0[self.nr:] = plane_through(pts)
        self._channels(("plane",), [0])

    def evaluate(self, x):
        X, psi = self.robot.fk_jacobian(self.qm, x[:self.nr])
        n = x[self.nr:]
        p = X[:, :3]
        pred = p @ n + 1.0
        W = np.concatenate([np.einsum("i,min->mn", n, psi[:, :3, :]), p], axis=1)
        return -pred, W

    def consistent_twin(self, x):
        """Contact points moved onto the plane of ``x`` along its normal
        (IK of ``x``, the orientation kept as far as the arm allows)."""
        X = self.robot.fk(self.qm, x[:self.nr])
        n = x[self.nr:]
        p = X[:, :3] - np.outer(X[:, :3] @ n + 1.0, n) / (n @ n)
        keep = []
        for i in range(len(p)):
            try:
                keep.append(self.robot.move_to(self.qm[i], p[i], x[:self.nr]))
            except UnreachablePose:
                pass  # a contact point the model cannot reach on the plane drops out
        twin = copy.copy(self)
        twin.qm = np.array(keep).reshape(-1, self.qm.shape[1])
        twin.n_poses = len(twin.qm)
        twin.row_channel = np.zeros(twin.n_poses, dtype=int)
        return twin
