"""Robot models known to the station: the built-ins by name, any serial robot
(:class:`calibration.robots.serial.SerialRobot`) from a robot file
(:class:`calibration.robots.dh_form.SerialSpec`, read by :mod:`drivers.robot_file`) or
a URDF (:class:`calibration.robots.urdf.UrdfSpec`, read by :mod:`drivers.urdf_file`)."""
from __future__ import annotations

from calibration.errors import ConfigError
from calibration.robots.base import RobotModel

ROBOTS = ("agebot-sm", "agebot-pm")
# what kind of robot a method needs (MethodInfo.kind) -> robots of that kind
KINDS = ("serial", "parallel-wrist")
# the built-in robot of each kind (the station's sessions and planner know these)
BUILTIN = {"serial": "agebot-sm", "parallel-wrist": "agebot-pm"}


def get_robot(robot) -> RobotModel:
    """The robot model of ``robot``: a built-in name (``agebot-sm``, ``agebot-pm``),
    a parsed robot file (``SerialSpec``), a URDF robot's chain (``UrdfSpec``) or a
    model (returned as is)."""
    if isinstance(robot, RobotModel):
        return robot
    if robot == "agebot-sm":
        from calibration.robots.agebot_sm import AgebotSM

        return AgebotSM()
    if robot == "agebot-pm":
        from calibration.robots.agebot_pm import AgebotPM

        return AgebotPM()
    from calibration.robots.serial import SerialRobot, SerialSpec
    from calibration.robots.urdf import UrdfSpec

    if isinstance(robot, (SerialSpec, UrdfSpec)):   # the one model of a serial chain
        return SerialRobot(robot)
    raise ConfigError(f"unknown robot {robot!r} (known: {', '.join(ROBOTS)}, or a robot file)",
                      key="robot")
