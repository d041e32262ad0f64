"""sm-self-redundancy (report 7.3): the end effector is brought to the same
``(x, y)`` with different ``phi`` (poses of one ``group``); no sensor.

For each group, every pose after the first gives the rows
``0 - (X_first[x, y] - X_other[x, y])`` (eq. 68; z is dropped: its row holds
only the rail and is always singular). ``q1_off, q2_off, k1, theta0, a0`` have no
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
        self._channels(("dx", "dy"), [0, 1])
        self.row_channel = np.tile([0, 1], self.n_pose_rows)

    @property
    def p(self) -> int:
        return 2

    def evaluate(self, x):
        X, psi = self.robot.fk_jacobian(self.qm, x)
        pred = X[self.first, :2] - X[self.other, :2]
        J = psi[self.first, :2, :] - psi[self.other, :2, :]
        return (-pred).reshape(-1), J.reshape(-1, self.nr)

    def consistent_twin(self, x):
        """Poses moved so that the model ``x`` puts each group at one (x, y):
        the other poses of a group go to the first pose's (x, y), keeping their
        z and phi (IK of ``x``)."""
        X = self.robot.fk(self.qm, x)
        qm = self.qm.copy()
        for f, o in zip(self.first, self.other):
            target = np.array([X[f, 0], X[f, 1], X[o, 2], X[o, 3]])
            try:
                qm[o] = self.robot.ik(target, x)
            except UnreachablePose:
                qm[o] = qm[f]  # a pair that cannot be made consistent drops out (zero rows)
        twin = copy.copy(self)
        twin.qm = qm
        return twin
