"""The station configuration: one TOML file parsed once into frozen dataclasses.

House style 6: raw dicts never leave this module and its section modules. Every error is a
:class:`ConfigError` naming the file and the key path, e.g.
``stations/sim.toml: drawwire.port: expected an integer``; unknown keys are
errors, missing required keys are named. Layout (see
``fixtures/stations/example-real.toml`` for every key, annotated)::

    robot = "agebot-sm"              # or robot_file = "arm.toml" (any serial robot; relative
                                     # to this file; robot, if given, must be its name)
    [canopen]        interface, channel, host, port, nodes, increments_per_unit, ...
    [canopen.bus]    further python-can keyword arguments (bitrate, ...)
    [inclinometer]   port (device or pyserial URL), baudrate, timeout
    [inclinometer.axes]  channel = { raw = "pitch", sign = 1, offset_rad = 0.0, range_rad = 1.05 }
                     (range_rad optional: the sensor reads |value| up to it)
    [drawwire]       mode "tcp" | "rtu", host/port or serial_port, device_id, ...
    [mocap]          host, port, labels, frames, timeout, volume = {min, max}, viewpoint,
                     view_angle_deg, outward (QTM motion capture; drivers/config_mocap.py)
    [snapshot]       samples, period, settle, timeout
    [snapshot.std_limits] / [snapshot.drift_limits] / [snapshot.noise_floor]
    [session]        retry_window: s a failing pose is retried before its device is
                     judged gone (0: three retries)
    [envelope]       qm_min, qm_max (per actuator): the range the station may command
                     (the wrist's slider stroke), actuator units; poll, latency;
                     [envelope.tolerance] channel = value (the live watch)

Endpoint values the simulator picks at run time are written as the placeholder
``"@endpoints"`` and filled by :func:`drivers.endpoints.with_endpoints` from the endpoints JSON of
``app.py simulate --endpoints FILE`` (cli.md). Units: SI, radians, seconds;
actuator values in actuator units of ``Q = K*Qm + Q_off``.

This module holds the whole (:class:`StationConfig`, :func:`load_station_config`,
:func:`parse_station_config`) and the config's robot (:func:`robot_of_config`,
:func:`check_config_robot`). Each section's dataclass and reader live in a module of its
own, their names importable from here as well: ``[canopen]``, ``[inclinometer]`` and
``[drawwire]`` in :mod:`drivers.config_devices`; ``[snapshot]``, ``[envelope]``,
``[session]`` and ``[display]`` in :mod:`drivers.config_session`; ``[mocap]`` in
:mod:`drivers.config_mocap`. The typed key reading lives in :mod:`drivers.config_reader`
(:class:`KeyReader`, :func:`frozen_map`, :func:`load_json`; importable from here as
well), the endpoints merge in :mod:`drivers.endpoints` (:func:`with_endpoints`,
:func:`load_endpoints`), which builds on this module and not the other way round.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping

from calibration.errors import ConfigError
from drivers.config_devices import (INCLINOMETER_CHANNELS, RAW_AXES, AxisMap, CanopenConfig,
                                    DrawwireConfig, InclinometerConfig, _canopen, _drawwire,
                                    _inclinometer)
from drivers.config_mocap import MocapConfig, _mocap
from drivers.config_reader import (MAX_MOVE_S, MAX_PERIOD_S, MAX_TIMEOUT_S, PLACEHOLDER,
                                   KeyReader, decode_text, frozen_map, load_json, parse_toml)
from drivers.config_session import (DISPLAY_ANGLES, DISPLAY_LENGTHS, ENVELOPE_TOLERANCE,
                                    LIMIT_CHANNEL, MAX_RETRY_WINDOW_S, DisplayConfig,
                                    EnvelopeConfig, SessionConfig, SnapshotConfig, _display,
                                    _envelope, _session, _snapshot)

__all__ = ["DISPLAY_ANGLES", "DISPLAY_LENGTHS", "ENVELOPE_TOLERANCE", "INCLINOMETER_CHANNELS",
           "LIMIT_CHANNEL", "MAX_MOVE_S", "MAX_PERIOD_S", "MAX_RETRY_WINDOW_S", "MAX_TIMEOUT_S",
           "PLACEHOLDER", "RAW_AXES", "ROBOT_AXES",
           "AxisMap", "CanopenConfig", "DisplayConfig", "DrawwireConfig", "EnvelopeConfig",
           "InclinometerConfig", "KeyReader", "MocapConfig", "SessionConfig",
           "SnapshotConfig", "StationConfig", "check_config_robot", "frozen_map", "load_json",
           "load_station_config", "parse_station_config", "robot_of_config"]

ROBOT_AXES = {"agebot-sm": 4, "agebot-pm": 3}


@dataclass(frozen=True)
class StationConfig:
    """The whole station. ``inclinometer``/``drawwire`` are None where the station has none;
    ``unresolved`` lists the key paths still holding ``"@endpoints"``."""

    robot: str
    canopen: CanopenConfig
    snapshot: SnapshotConfig
    inclinometer: InclinometerConfig | None = None
    drawwire: DrawwireConfig | None = None
    mocap: MocapConfig | None = None
    source: str | None = None
    unresolved: tuple[str, ...] = ()
    display: DisplayConfig = DisplayConfig()
    envelope: EnvelopeConfig = dataclasses.field(default_factory=EnvelopeConfig)
    session: SessionConfig = SessionConfig()
    spec: Any = None    # the robot file's SerialSpec (``robot_file``), or None for a built-in

    @property
    def robot_model(self):
        """What :func:`calibration.robots.get_robot` takes: the robot file's spec or the
        built-in robot's name."""
        return self.spec if self.spec is not None else self.robot

    def require_resolved(self) -> "StationConfig":
        """Self, or ConfigError naming the first endpoint placeholder not yet filled."""
        if self.unresolved:
            raise ConfigError(f"{PLACEHOLDER!r} not filled: start the simulator with "
                              "--endpoints FILE and apply it (with_endpoints)",
                              source=self.source, key=self.unresolved[0])
        return self


# -- parsing --------------------------------------------------------------------------
def load_station_config(path: str | Path) -> StationConfig:
    """Read and parse a station TOML file; errors name ``path`` and the key."""
    path = Path(path)
    try:
        raw = path.read_bytes()
    except OSError as e:
        raise ConfigError(f"cannot read: {e.strerror or e}", source=str(path)) from e
    return parse_station_config(parse_toml(decode_text(raw, str(path)), str(path)), str(path))


def parse_station_config(data: Mapping[str, Any], source: str | None = None, *,
                         spec=None) -> StationConfig:
    """Parse a TOML document (already a dict) into a :class:`StationConfig`. ``spec``: the
    robot file's :class:`~calibration.robots.serial.SerialSpec` when the caller read it
    already (the document then has no ``robot_file``)."""
    top = KeyReader(data, "", source)
    if "robot_file" in top.data:
        from drivers.robot_file import load_robot_file

        base = Path(source).parent if source else Path(".")
        spec = load_robot_file(_robot_file_ref(top, base))
    if spec is not None:
        robot = top.str("robot", default=spec.name)
        if robot != spec.name:
            top.fail("robot", f"{robot!r} is not the robot file's name {spec.name!r}")
        n = len(spec.joints)
    else:
        robot = top.choice("robot", tuple(ROBOT_AXES))
        n = ROBOT_AXES[robot]
    unresolved: list[str] = []
    canopen = _canopen(top.table("canopen"), n, unresolved)
    incl = top.table("inclinometer", required=False)
    dw = top.table("drawwire", required=False)
    mc = top.table("mocap", required=False)
    snap = top.table("snapshot", required=False)
    disp = top.table("display", required=False)
    env = top.table("envelope", required=False)
    ses = top.table("session", required=False)
    config = StationConfig(
        robot=robot, canopen=canopen,
        inclinometer=_inclinometer(incl, unresolved) if incl else None,
        drawwire=_drawwire(dw, unresolved) if dw else None,
        mocap=_mocap(mc, unresolved) if mc else None,
        snapshot=_snapshot(snap) if snap else SnapshotConfig(),
        source=source, unresolved=tuple(unresolved),
        display=_display(disp) if disp else DisplayConfig(), envelope=_envelope(env, n) if env else EnvelopeConfig(),
        session=_session(ses) if ses else SessionConfig(), spec=spec)
    top.finish()
    return config

def _robot_file_ref(top: KeyReader, base: Path) -> str:
    """The config's ``robot_file`` (relative to the config's folder) as the station names
    it: a URDF with its chain, ``base_link`` and ``tip_link`` (:func:`drivers.robot_file.
    urdf_ref`), else the robot file's path."""
    from drivers.robot_file import urdf_ref
    from drivers.urdf_file import is_urdf

    path = base / top.str("robot_file")
    if is_urdf(str(path)):
        return urdf_ref(path, top.str("base_link"), top.str("tip_link"))
    for key in ("base_link", "tip_link"):
        if key in top.data:
            top.fail(key, "chooses the chain of a URDF robot; robot_file is not a URDF")
    return str(path)


def robot_of_config(path) -> str:
    """The robot of the station config ``path``: a built-in name, or the path of the robot
    file it names (``robot_file``, relative to the config's folder; a URDF's with its
    chain, :func:`drivers.robot_file.urdf_ref`)."""
    import tomllib

    config = load_station_config(path)
    if config.spec is not None:      # read already: the path as the config gives it
        with open(path, "rb") as f:
            data = tomllib.load(f)
        return _robot_file_ref(KeyReader(data, "", str(path)), Path(path).parent)
    return config.robot


def _chain(spec) -> tuple:
    """A URDF robot's chain ``(base_link, tip_link)`` (a robot file's: empty)."""
    return tuple(spec.source.get(k) for k in ("base_link", "tip_link") if k in spec.source)


def check_config_robot(config: StationConfig, robot: str) -> None:
    """Refuse a station config that is not for ``robot`` (a built-in name, or the path of a
    robot file: the config's robot file must be that file, by its checksum)."""
    from calibration.robots import ROBOTS

    if robot not in ROBOTS:       # a robot file
        from drivers.robot_file import load_robot_file

        spec = load_robot_file(robot)
        if config.spec is None or config.spec.source["sha256"] != spec.source["sha256"] or \
                _chain(config.spec) != _chain(spec):
            raise ConfigError(f"the station config is for {config.robot}, not the robot "
                              f"file {robot}", source=config.source, key="robot_file")
    elif config.robot != robot:
        raise ConfigError(f"the station config is for {config.robot}, not {robot}",
                          source=config.source, key="robot")
