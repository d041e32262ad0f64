"""What a simulated station is made of: its truth file (what the robot really is) and its
station config (the devices it looks like), the fixtures' by default; :func:`build`
makes the :class:`~drivers.sim.sim_station.SimStation` of them.

A built-in robot's defaults are ``fixtures/truth/<robot>.json`` and
``fixtures/stations/sim-<sm|pm>.toml``; a robot file's are its nominal truth and its
default station (:func:`drivers.sim.serial_robot.sim_config`); a URDF robot needs a truth
file (its true URDF, the motion-capture room). A truth file of another robot is refused
in one line naming the file (:func:`truth_of`). Used by ``app.py simulate``
(:mod:`drivers.sim.server`), the simulator's child process
(:mod:`drivers.sim.simulator_process`) and ``devices check --simulate``.
"""
from __future__ import annotations

from pathlib import Path

from calibration.errors import ConfigError
from drivers.config import StationConfig, load_station_config
from drivers.sim.serial_robot import is_robot_file, nominal_truth, sim_config
from drivers.sim.sim_station import SimStation
from drivers.sim.truth import SimTruth, load_truth

ROOT = Path(__file__).resolve().parents[2]
FIXTURES = ROOT / "fixtures"


def default_config_path(robot: str) -> Path:
    return FIXTURES / "stations" / f"sim-{robot.removeprefix('agebot-')}.toml"


def default_truth_path(robot: str) -> Path:
    return FIXTURES / "truth" / f"{robot}.json"


def build(robot: str, truth: str | None = None, config: str | None = None, *,
          seed: int | None = None, pose_noise: bool = False) -> SimStation:
    """A :class:`SimStation` from file names (defaults: the fixtures), not started."""
    c = load_sim_config(robot, config, truth)
    return SimStation(truth_of(robot, truth, c), c, seed=seed, pose_noise=pose_noise)


def truth_of(robot: str, truth: str | None, config: StationConfig | None = None):
    """The simulator's truth of ``robot`` (a built-in name or a robot file): the file
    ``truth`` (default: the built-in's fixture, a robot file's nominal), refused in one
    line where it is of another robot."""
    if is_robot_file(robot):     # a robot file: the truth is of it (default: its nominal)
        spec = config.spec if config is not None and config.spec is not None else None
        if spec is None:
            from drivers.robot_file import load_robot_file

            spec = load_robot_file(robot)
        if hasattr(spec, "base_link"):      # a URDF robot: its truth is a true URDF
            return _urdf_truth_of(robot, spec, truth)
        t = load_truth(truth) if truth else nominal_truth(robot)
        if t.spec is None or t.spec.source["sha256"] != spec.source["sha256"]:
            raise ConfigError(f"the truth file is not of the robot file {robot}"
                              + (f" (it is of {t.robot})" if t.robot else ""),
                              source=t.source, key="robot_file")
        return t
    t = load_truth(truth) if truth else load_truth(default_truth_path(robot))
    if t.robot != robot:
        raise ConfigError(f"the truth file is for {t.robot}, not {robot}", source=t.source,
                          key="robot")
    return t


def _urdf_truth_of(robot: str, spec, truth: str | None) -> SimTruth:
    """The truth file of a URDF robot: needed (what the robot really is, where the room
    is), refused in one line where its robot is another."""
    from drivers.sim.urdf_truth import same_chain

    if not truth:
        raise ConfigError(f"a simulated {robot} needs --truth: a truth file of the URDF robot "
                          "(its true URDF, the motion-capture room, the points on the tool)")
    t = load_truth(truth)
    why = ("it is of " + t.robot if t.robot != "urdf" else same_chain(t.spec, spec))
    if why:
        raise ConfigError(f"the truth file is not of the URDF robot {robot}: {why}",
                          source=t.source, key="urdf")
    return t


def load_sim_config(robot: str, config: str | None = None,
                    truth: str | None = None) -> StationConfig:
    """The simulated station's config: ``config``, else the fixture of a built-in robot
    or the default station of a robot file (:func:`drivers.sim.serial_robot.sim_config`;
    a URDF robot's with its ``truth`` file's motion-capture room)."""
    if config:
        return load_station_config(config)
    if is_robot_file(robot):
        from drivers.robot_file import split_urdf_ref

        t = load_truth(truth) if truth and split_urdf_ref(robot) is not None else None
        return sim_config(robot, t if t is not None and t.robot == "urdf" else None)
    return load_station_config(default_config_path(robot))
