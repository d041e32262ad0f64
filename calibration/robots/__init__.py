"""Robot models known to the station, by the name used in traces and files."""
from __future__ import annotations

from calibration.errors import ConfigError
from calibration.robots.base import RobotModel

ROBOTS = ("agebot-sm", "agebot-pm")


def get_robot(name: str) -> RobotModel:
    """The robot model called ``name`` (``agebot-sm`` or ``agebot-pm``)."""
    if name == "agebot-sm":
        from calibration.robots.agebot_sm import AgebotSM

        return AgebotSM()
    if name == "agebot-pm":
        from calibration.robots.agebot_pm import AgebotPM

        return AgebotPM()
    raise ConfigError(f"unknown robot {name!r} (known: {', '.join(ROBOTS)})", key="robot")
