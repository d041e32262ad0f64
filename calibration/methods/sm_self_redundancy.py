"""sm-self-redundancy (report 7.3): the end effector is brought to the same
point with different orientations (poses of one ``group``); no sensor.

For each group, every pose after the first gives the rows
``0 - (X_first[c] - X_other[c])`` (eq. 68) over the robot's ``group_rows`` ``c``:
AGEBOT's ``x, y`` (z is dropped: its row holds only the rail and is always
singular), a robot file's ``x, y, z``. On AGEBOT: ``q1_off, q2_off, k1, theta0, a0`` have no
influence; ``L4`` is dependent on the other lengths (the scale of a
self-calibration) and influences the model: its nominal must be right.
"""
from __future__ import annotations

import copy

import numpy as np

from calibration.errors import CalibrationError, UnreachablePose
from calibration.methods.base import RobotMethod


class SelfRedundancy(RobotMethod):
    method = "sm-self-redundancy"
    default_damping = 1e-4

    def __init__(self, robot, qm, measured: dict, nominal, *, group):
        super().__init__(robot, qm, nominal)
        if group is None:
            raise CalibrationError("sm-self-redundancy needs a 'group' for every pose")
        group = np.asarray(group)
        first, other = [], []
        for gid in np.unique(group):
            idx = np.flatnonzero(group == gid)
            if idx.size < 2:
                raise CalibrationError(f"group {int(gid)} has a single pose; each group needs "
                                       f"two or more poses at the same (x, y)")
            first += [idx[0]] * (idx.size - 1)
            other += list(idx[1:])
        self.first, self.other = np.array(first), np.array(other)
        self.n_pose_rows = len(self.first)
        self.rows = list(robot.group_rows)
        self._channels(tuple("d" + "xyz"[c] for c in self.rows), list(range(len(self.rows))))
        self.row_channel = np.tile(np.arange(len(self.rows)), self.n_pose_rows)

    @property
    def p(self) -> int:
        return len(self.rows)

    def evaluate(self, x):
        X, psi = self.robot.fk_jacobian(self.qm, x)
        c = self.rows
        pred = X[self.first][:, c] - X[self.other][:, c]
        J = psi[self.first][:, c, :] - psi[self.other][:, c, :]
        return (-pred).reshape(-1), J.reshape(-1, self.nr)

    def consistent_twin(self, x):
        """Poses moved so that the model ``x`` puts each group at one point: the
        other poses of a group go to the first pose's coordinates ``group_rows``,
        keeping the rest of their pose as far as the arm allows (IK of ``x``)."""
        X = self.robot.fk(self.qm, x)
        qm = self.qm.copy()
        for f, o in zip(self.first, self.other):
            target = X[o, :3].copy()
            target[self.rows] = X[f, self.rows]
            try:
                qm[o] = self.robot.move_to(self.qm[o], target, x)
            except UnreachablePose:
                qm[o] = qm[f]  # a pair that cannot be made consistent drops out (zero rows)
        twin = copy.copy(self)
        twin.qm = qm
        return twin
