"""Shared pieces of the methods: data checks and the serial arm's FK + Jacobian."""
from __future__ import annotations

import numpy as np

from calibration.errors import CalibrationError
from calibration.model import MeasurementModel, require_finite


class RobotMethod(MeasurementModel):
    """A method over a robot model; ``x`` starts with the robot's parameters,
    extra parameters (e.g. a plane) follow."""

    robot_kind = "serial"
    extra_names: tuple[str, ...] = ()
    evaluates_everywhere = True  # a serial chain's forward kinematics (PMMethod: not)

    def __init__(self, robot, qm, nominal):
        if robot.kind != self.robot_kind:
            raise CalibrationError(f"method {self.method} needs a {self.robot_kind} robot; "
                                   f"{robot.name} is a {robot.kind} one")
        self.robot = robot
        self.qm = require_finite("qm", np.atleast_2d(qm))
        if self.qm.shape[1] != robot.n_actuators:
            raise CalibrationError(f"qm has {self.qm.shape[1]} values per pose; robot "
                                   f"{robot.name} has {robot.n_actuators} actuators")
        self.n_poses = self.qm.shape[0]
        self.names = tuple(robot.param_names) + tuple(self.extra_names)
        nominal = np.asarray(nominal, dtype=float)
        if nominal.shape != (len(self.names),):
            raise CalibrationError(f"nominal has {nominal.size} values, method {self.method} "
                                   f"needs {len(self.names)} ({', '.join(self.names)})")
        self.nominal = nominal
        self.x0 = nominal.copy()
        conditioning = getattr(robot, "warnings", None)
        if conditioning is not None:
            self.notes = tuple(conditioning(nominal[:robot.n_params]))

    @property
    def nr(self) -> int:
        """Number of robot parameters in x."""
        return self.robot.n_params

    def _channels(self, names, per_pose_rows):
        self.channels = tuple(names)
        self.row_channel = np.tile(np.asarray(per_pose_rows), self.n_poses)


def channel(data: dict, name: str, method: str, shape=None) -> np.ndarray:
    if name not in data:
        raise CalibrationError(f"method {method} needs the measured channel {name!r}")
    a = require_finite(name, data[name])
    if shape is not None and a.shape[1:] != shape:
        raise CalibrationError(f"channel {name!r} must have shape (poses, {', '.join(map(str, shape))}), "
                               f"got {a.shape}")
    return a
