"""The station configuration: one TOML file parsed once into frozen dataclasses.

House style 6: raw dicts never leave this module (and its two helpers below). Every error is a
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

The typed key reading lives in :mod:`drivers.config_reader` (:class:`KeyReader`,
:func:`frozen_map`, :func:`load_json`; importable from here as well), the
endpoints merge in :mod:`drivers.endpoints` (:func:`with_endpoints`,
:func:`load_endpoints`), which builds on this module and not the other way round.
"""
from __future__ import annotations

import dataclasses
import math
import re
from dataclasses import dataclass
from pathlib import Path
from types import MappingProxyType
from typing import Any, Mapping

import numpy as np

from calibration.errors import ConfigError
from drivers.config_mocap import MocapConfig, _mocap
from drivers.config_reader import (PLACEHOLDER, KeyReader, decode_text, frozen_map,
                                   load_json, parse_toml)

__all__ = ["INCLINOMETER_CHANNELS", "LIMIT_CHANNEL", "PLACEHOLDER", "RAW_AXES", "ROBOT_AXES",
           "AxisMap", "CanopenConfig", "DrawwireConfig", "EnvelopeConfig", "InclinometerConfig",
           "KeyReader",
           "SnapshotConfig", "StationConfig", "frozen_map", "load_json",
           "load_station_config", "parse_station_config"]

ROBOT_AXES = {"agebot-sm": 4, "agebot-pm": 3}
INCLINOMETER_CHANNELS = ("tilt", "roll", "pitch", "yaw")
RAW_AXES = ("roll", "pitch", "yaw")
LIMIT_CHANNEL = re.compile(r"^(qm[0-9]*|tilt|roll|pitch|yaw|distance)$")


@dataclass(frozen=True)
class CanopenConfig:
    """The actuators' CANopen bus (docs/real-station.md, "The CANopen drives").

    interface/channel: python-can interface (``socketcand``, ``socketcan``, ...) and channel.
    host, port:        socketcand server (None for other interfaces).
    bus_options:       further python-can ``Bus(...)`` keyword arguments (``bitrate``, ...).
    mode:              ``"cia402"`` drives (the station moves the robot) or ``"cia406"`` encoders.
    nodes:             node id of each actuator, in actuator order.
    increments_per_unit: encoder increments per actuator unit, per actuator (fixed, not calibrated).
    profile_velocity / profile_acceleration: per actuator, actuator units/s and /s^2.
    sdo_timeout, move_timeout: seconds for one SDO transfer / one commanded move.
    heartbeat_period:  producer heartbeat time (0x1017) the nodes are given, s.
    heartbeat_timeout: silence after which the master declares a node dead, s.
    sync_period:       SYNC period, s (TPDOs are sampled at SYNC).
    """

    interface: str
    channel: str
    nodes: tuple[int, ...]
    increments_per_unit: tuple[float, ...]
    host: str | None = None
    port: int | None = None
    bus_options: Mapping[str, Any] = dataclasses.field(default_factory=lambda: MappingProxyType({}))
    mode: str = "cia402"
    profile_velocity: tuple[float, ...] = ()
    profile_acceleration: tuple[float, ...] = ()
    sdo_timeout: float = 0.5
    move_timeout: float = 30.0
    heartbeat_period: float = 0.1
    heartbeat_timeout: float = 0.5
    sync_period: float = 0.05

    def bus_kwargs(self) -> dict[str, Any]:
        """Keyword arguments for ``can.Bus(**kwargs)``."""
        kw: dict[str, Any] = {"interface": self.interface, "channel": self.channel}
        if self.host is not None:
            kw["host"] = self.host
        if self.port is not None:
            kw["port"] = self.port
        kw.update(self.bus_options)
        return kw


@dataclass(frozen=True)
class AxisMap:
    """One inclinometer output channel: ``value = sign * raw_axis + offset_rad`` (rad);
    ``range_rad``: the sensor reads ``|value|`` up to this (None: not stated), so the
    station plans no pose, and records none, beyond it."""

    raw: str
    sign: float = 1.0
    offset_rad: float = 0.0
    range_rad: float | None = None


@dataclass(frozen=True)
class InclinometerConfig:
    """The serial inclinometer. ``port``: device path or pyserial URL (``socket://h:p``);
    ``timeout``: s without a valid frame before a timeout fault; ``axes``: output
    channel (``tilt``, ``roll``, ``pitch``) -> :class:`AxisMap`."""

    port: str | None
    axes: Mapping[str, AxisMap]
    baudrate: int = 9600
    timeout: float = 1.0


@dataclass(frozen=True)
class DrawwireConfig:
    """The Modbus draw-wire sensor: ``distance = counts * metres_per_count + offset_m``.

    mode ``"tcp"`` uses host/port; ``"rtu"`` uses serial_port, baudrate, parity, stopbits.
    word_order: ``"high-first"`` or ``"low-first"`` for the UINT32 position count.
    timeout: s per Modbus request.
    """

    mode: str
    metres_per_count: float
    host: str | None = None
    port: int | None = None
    serial_port: str | None = None
    baudrate: int = 19200
    parity: str = "N"
    stopbits: int = 1
    device_id: int = 1
    word_order: str = "high-first"
    offset_m: float = 0.0
    timeout: float = 1.0


# units the operator reads (station/outputs/units.py); files stay SI
DISPLAY_LENGTHS = ("mm", "m", "cm", "um")
DISPLAY_ANGLES = ("deg", "rad", "mrad")


@dataclass(frozen=True)
class DisplayConfig:
    """``[display]``: the units of the numbers shown to people (mm and degrees by
    default); traces and parameter files are SI whatever this says."""

    length: str = "mm"
    angle: str = "deg"


@dataclass(frozen=True)
class SnapshotConfig:
    """How one pose is measured (see :mod:`drivers.snapshot`).

    samples: readings per channel; period: s between them; settle: s to wait after
    the motion; timeout: s per device read. ``std_limits``/``drift_limits``/``noise_floor``:
    channel -> limit in the channel's unit; the key ``qm`` covers every ``qmN``.
    """

    samples: int = 10
    period: float = 0.02
    settle: float = 0.5
    timeout: float = 1.0
    std_limits: Mapping[str, float] = dataclasses.field(default_factory=lambda: MappingProxyType({}))
    drift_limits: Mapping[str, float] = dataclasses.field(default_factory=lambda: MappingProxyType({}))
    noise_floor: Mapping[str, float] = dataclasses.field(default_factory=lambda: MappingProxyType({}))


#: default tolerances of the envelope's live watch (channel units: m, rad)
ENVELOPE_TOLERANCE = {"distance": 0.05, "tilt": 0.0873, "roll": 0.0873, "pitch": 0.0873,
                      "yaw": 0.0873, "marker": 0.05}   # marker: each coordinate of a point


@dataclass(frozen=True)
class EnvelopeConfig:
    """The session's safety envelope (:mod:`station.planning.envelope`).

    qm_min, qm_max: per actuator, the range the station may command (actuator units;
                    None: the config sets no limit on that side). For the wrist: the
                    sliders' stroke.
    tolerance:      channel -> largest ``|live reading - model prediction|`` tolerated
                    while moving (channel units: m, rad); channels not listed are not
                    watched. Default :data:`ENVELOPE_TOLERANCE`.
    poll:           s between live readings while moving.
    latency:        s a sensor's reading may lag the actuators' (frame period, bus,
                    filter): a reading is compared with the predictions along the
                    path travelled over that time.
    """

    qm_min: tuple[float, ...] | None = None
    qm_max: tuple[float, ...] | None = None
    tolerance: Mapping[str, float] = dataclasses.field(
        default_factory=lambda: MappingProxyType(dict(ENVELOPE_TOLERANCE)))
    poll: float = 0.05
    latency: float = 0.15

    @property
    def qm_range(self) -> np.ndarray | None:
        """``(n, 2)`` of ``(min, max)`` per actuator (-inf/inf on an open side), or None
        when neither side is set."""
        if self.qm_min is None and self.qm_max is None:
            return None
        n = len(self.qm_min if self.qm_min is not None else self.qm_max)
        lo = np.full(n, -np.inf) if self.qm_min is None else np.asarray(self.qm_min, float)
        hi = np.full(n, np.inf) if self.qm_max is None else np.asarray(self.qm_max, float)
        return np.column_stack([lo, hi])


@dataclass(frozen=True)
class SessionConfig:
    """``[session]``: how a headless session rides out a device's trouble.

    retry_window: seconds a failing pose (or the reference step) is retried, after the
                  growing pauses of :func:`station.session.device_loss.backoff`, before the
                  session asks whether its device is gone (then it stops, naming it).
                  0 (default): three retries, after 0.25, 0.5 and 1 s. A node that
                  answers late for a while (a busy bus, a drive's firmware) is ridden
                  out with a window longer than the while.
    """

    retry_window: float = 0.0


#: the longest retry window a station config may set (s)
MAX_RETRY_WINDOW_S = 3600.0
#: the longest timeout of one request or read, one motion, and one period (s): a
#: longer one is a typing slip that would hang a command as good as for ever
MAX_TIMEOUT_S = 60.0
MAX_MOVE_S = 3600.0
MAX_PERIOD_S = 10.0


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


def _canopen(r: KeyReader, n: int, unresolved: list[str]) -> CanopenConfig:
    mode = r.choice("mode", ("cia402", "cia406"), default="cia402")
    nodes = r.int_list("nodes", length=n, lo=1, hi=127)
    if len(set(nodes)) != len(nodes):
        r.fail("nodes", "node ids must be distinct")
    hb = r.float("heartbeat_period", default=0.1, lo=0.0, lo_open=True, hi=MAX_PERIOD_S)
    bus = r.table("bus", required=False)
    cfg = CanopenConfig(
        interface=r.str("interface"), channel=r.str("channel", default="can0"),
        host=r.str("host", default=None, placeholder=unresolved),
        port=r.int("port", default=None, lo=1, hi=65535, placeholder=unresolved),
        bus_options=frozen_map(bus.rest() if bus else {}), mode=mode, nodes=nodes,
        increments_per_unit=r.float_list("increments_per_unit", length=n, lo=0.0, lo_open=True),
        profile_velocity=r.float_list("profile_velocity", length=n, lo=0.0, lo_open=True,
                                      default=(100.0,) * n, scalar_ok=True),
        profile_acceleration=r.float_list("profile_acceleration", length=n, lo=0.0, lo_open=True,
                                          default=(1000.0,) * n, scalar_ok=True),
        sdo_timeout=r.float("sdo_timeout", default=0.5, lo=0.0, lo_open=True, hi=MAX_TIMEOUT_S),
        move_timeout=r.float("move_timeout", default=30.0, lo=0.0, lo_open=True,
                             hi=MAX_MOVE_S),
        heartbeat_period=hb,
        heartbeat_timeout=r.float("heartbeat_timeout", default=5 * hb, lo=hb, lo_open=True,
                                  hi=MAX_TIMEOUT_S),
        sync_period=r.float("sync_period", default=0.05, lo=0.0, lo_open=True, hi=MAX_PERIOD_S))
    r.finish()
    return cfg


def _inclinometer(r: KeyReader, unresolved: list[str]) -> InclinometerConfig:
    axes_r = r.table("axes")
    axes = {}
    for ch in axes_r.keys():
        if ch not in INCLINOMETER_CHANNELS:
            axes_r.fail(ch, f"unknown channel (known: {', '.join(INCLINOMETER_CHANNELS)})")
        a = axes_r.table(ch)
        sign = a.float("sign", default=1.0)
        if sign not in (1.0, -1.0):
            a.fail("sign", "expected 1 or -1")
        axes[ch] = AxisMap(raw=a.choice("raw", RAW_AXES), sign=sign,
                           offset_rad=a.float("offset_rad", default=0.0),
                           range_rad=a.float("range_rad", default=None, lo=0.0, hi=math.pi,
                                             lo_open=True))
        a.finish()
    if not axes:
        r.fail("axes", "map at least one channel (tilt, roll, pitch or yaw)")
    axes_r.finish()
    cfg = InclinometerConfig(
        port=r.str("port", placeholder=unresolved), axes=frozen_map(axes),
        baudrate=r.int("baudrate", default=9600, lo=1, placeholder=unresolved),
        timeout=r.float("timeout", default=1.0, lo=0.0, lo_open=True, hi=MAX_TIMEOUT_S))
    r.finish()
    return cfg


def _drawwire(r: KeyReader, unresolved: list[str]) -> DrawwireConfig:
    mode = r.choice("mode", ("tcp", "rtu"))
    tcp = mode == "tcp"
    cfg = DrawwireConfig(
        mode=mode, metres_per_count=r.float("metres_per_count", lo=0.0, lo_open=True),
        host=r.str("host", placeholder=unresolved) if tcp else None,
        port=r.int("port", lo=1, hi=65535, placeholder=unresolved) if tcp else None,
        serial_port=None if tcp else r.str("serial_port", placeholder=unresolved),
        baudrate=r.int("baudrate", default=19200, lo=1),
        parity=r.choice("parity", ("N", "E", "O"), default="N"),
        stopbits=r.choice("stopbits", (1, 2), default=1),
        device_id=r.int("device_id", default=1, lo=0, hi=247, placeholder=unresolved),
        word_order=r.choice("word_order", ("high-first", "low-first"), default="high-first"),
        offset_m=r.float("offset_m", default=0.0),
        timeout=r.float("timeout", default=1.0, lo=0.0, lo_open=True, hi=MAX_TIMEOUT_S))
    r.finish()
    return cfg


def _limits(r: KeyReader, key: str) -> Mapping[str, float]:
    t = r.table(key, required=False)
    if t is None:
        return frozen_map({})
    out = {}
    for ch in t.keys():
        if not LIMIT_CHANNEL.match(ch):
            t.fail(ch, "unknown channel (known: qm, qmN, tilt, roll, pitch, yaw, distance)")
        out[ch] = t.float(ch, lo=0.0)
    t.finish()
    return frozen_map(out)


def _session(r: KeyReader) -> SessionConfig:
    cfg = SessionConfig(retry_window=r.float("retry_window", default=0.0, lo=0.0,
                                             hi=MAX_RETRY_WINDOW_S))
    r.finish()
    return cfg


def _display(r: KeyReader) -> DisplayConfig:
    cfg = DisplayConfig(length=r.choice("length", DISPLAY_LENGTHS, default="mm"),
                        angle=r.choice("angle", DISPLAY_ANGLES, default="deg"))
    r.finish()
    return cfg


def _envelope(r: KeyReader, n: int) -> EnvelopeConfig:
    lo = r.float_list("qm_min", length=n, default=None)
    hi = r.float_list("qm_max", length=n, default=None)
    if lo is not None and hi is not None and any(a >= b for a, b in zip(lo, hi)):
        r.fail("qm_max", "every qm_max must be above its qm_min")
    tol = dict(ENVELOPE_TOLERANCE)
    t = r.table("tolerance", required=False)
    if t is not None:
        for ch in t.keys():
            if ch not in ENVELOPE_TOLERANCE:
                t.fail(ch, f"unknown channel (known: {', '.join(ENVELOPE_TOLERANCE)})")
            tol[ch] = t.float(ch, lo=0.0, lo_open=True)
        t.finish()
    cfg = EnvelopeConfig(qm_min=lo, qm_max=hi, tolerance=frozen_map(tol),
                         poll=r.float("poll", default=0.05, lo=0.0, lo_open=True, hi=MAX_PERIOD_S),
                         latency=r.float("latency", default=0.15, lo=0.0, hi=MAX_PERIOD_S))
    r.finish()
    return cfg


def _snapshot(r: KeyReader) -> SnapshotConfig:
    cfg = SnapshotConfig(
        samples=r.int("samples", default=10, lo=1, hi=10000),
        period=r.float("period", default=0.02, lo=0.0, hi=MAX_PERIOD_S),
        settle=r.float("settle", default=0.5, lo=0.0, hi=MAX_TIMEOUT_S),
        timeout=r.float("timeout", default=1.0, lo=0.0, lo_open=True, hi=MAX_TIMEOUT_S),
        std_limits=_limits(r, "std_limits"), drift_limits=_limits(r, "drift_limits"),
        noise_floor=_limits(r, "noise_floor"))
    r.finish()
    return cfg


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
