"""Which robot kind a session has (:mod:`station.session.robot_kinds`)."""
from __future__ import annotations

from station.session.marker_kind import MarkersKind
from station.session.robot_kinds import ArmKind, RobotKind, SerialKind, WristKind


def robot_kind(session) -> RobotKind:
    """The kind of ``session``'s robot: a URDF robot measured by a point instrument, a
    robot file's (or URDF robot's) arm, the wrist or the arm."""
    if session.method == "sm-markers":
        return MarkersKind(session)
    if session.config.spec is not None:
        return SerialKind(session)
    if session.robot.name == "agebot-pm":
        return WristKind(session)
    return ArmKind(session)
