"""The station configuration: one TOML file parsed once into frozen dataclasses.

House style 6: raw dicts never leave this module. Every error is a
:class:`ConfigError` naming the file and the key path, e.g.
``stations/sim.toml: drawwire.port: expected an integer``; unknown keys are
errors, missing required keys are named. Layout (see
``fixtures/stations/example-real.toml`` for every key, annotated)::

    robot = "agebot-sm"
    [canopen]        interface, channel, host, port, nodes, increments_per_unit, ...
    [canopen.bus]    further python-can keyword arguments (bitrate, ...)
    [inclinometer]   port (device or pyserial URL), baudrate, timeout
    [inclinometer.axes]  channel = { raw = "pitch", sign = 1, offset_rad = 0.0 }
    [drawwire]       mode "tcp" | "rtu", host/port or serial_port, device_id, ...
    [snapshot]       samples, period, settle, timeout
    [snapshot.std_limits] / [snapshot.drift_limits] / [snapshot.noise_floor]

Endpoint values the simulator picks at run time are written as the placeholder
``"@endpoints"`` and filled by :func:`with_endpoints` from the endpoints JSON of
``app.py simulate --endpoints FILE`` (cli.md). Units: SI, radians, seconds;
actuator values in actuator units of ``Q = K*Qm + Q_off``.
"""
from __future__ import annotations

import dataclasses
import json
import re
import tomllib
from dataclasses import dataclass
from pathlib import Path
from types import MappingProxyType
from typing import Any, Mapping

from calibration.errors import ConfigError

ROBOT_AXES = {"agebot-sm": 4, "agebot-pm": 3}
INCLINOMETER_CHANNELS = ("tilt", "roll", "pitch")
RAW_AXES = ("roll", "pitch", "yaw")
LIMIT_CHANNEL = re.compile(r"^(qm[0-9]*|tilt|roll|pitch|distance)$")


@dataclass(frozen=True)
class CanopenConfig:
    """The actuators' CANopen bus (devices.md).

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
    """One inclinometer output channel: ``value = sign * raw_axis + offset_rad`` (rad)."""

    raw: str
    sign: float = 1.0
    offset_rad: float = 0.0


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


@dataclass(frozen=True)
class StationConfig:
    """The whole station. ``inclinometer``/``drawwire`` are None where the station has none;
    ``unresolved`` lists the key paths still holding ``"@endpoints"``."""

    robot: str
    canopen: CanopenConfig
    snapshot: SnapshotConfig
    inclinometer: InclinometerConfig | None = None
    drawwire: DrawwireConfig | None = None
    source: str | None = None
    unresolved: tuple[str, ...] = ()

    def require_resolved(self) -> "StationConfig":
        """Self, or ConfigError naming the first endpoint placeholder not yet filled."""
        if self.unresolved:
            raise ConfigError(f"{PLACEHOLDER!r} not filled: start the simulator with "
                              "--endpoints FILE and apply it (with_endpoints)",
                              source=self.source, key=self.unresolved[0])
        return self


# -- typed reading of one table -----------------------------------------------------------
PLACEHOLDER = "@endpoints"
_REQUIRED = object()


def frozen_map(d: Mapping) -> Mapping:
    """A read-only copy of ``d``."""
    return MappingProxyType(dict(d))


class KeyReader:
    """Typed access to one table of a config document, naming ``source`` and the key path.

    Each getter marks its key as used; :meth:`finish` rejects the keys nobody used.
    ``placeholder`` (a list) allows the value ``"@endpoints"``: the key path is
    appended to the list and None returned.
    """

    def __init__(self, data: Any, path: str, source: str | None, *, indexed: bool = False):
        self.path, self.source, self._indexed = path, source, indexed
        if not isinstance(data, Mapping):
            raise ConfigError(f"expected a table, got {type(data).__name__}",
                              source=source, key=path or None)
        self.data, self._used = data, set()

    def key(self, key) -> str:
        """The key path of ``key`` in this table (``drawwire.port``, ``canopen.nodes[2]``)."""
        if self._indexed:
            return f"{self.path}[{key}]"
        return f"{self.path}.{key}" if self.path else str(key)

    def fail(self, key: str, message: str):
        raise ConfigError(message, source=self.source, key=self.key(key))

    def keys(self) -> list[str]:
        return list(self.data)

    def _get(self, key, default, placeholder):
        self._used.add(key)
        if key not in self.data:
            if default is _REQUIRED:
                self.fail(key, "missing required key")
            return default, True
        v = self.data[key]
        if placeholder is not None and v == PLACEHOLDER:
            placeholder.append(self.key(key))
            return None, True
        return v, False

    def _range(self, key, v, lo, hi, lo_open):
        if lo is not None and (v <= lo if lo_open else v < lo):
            self.fail(key, f"{v!r} must be {'>' if lo_open else '>='} {lo}")
        if hi is not None and v > hi:
            self.fail(key, f"{v!r} must be <= {hi}")
        return v

    def str(self, key, default=_REQUIRED, placeholder=None):
        v, done = self._get(key, default, placeholder)
        if not done and (not isinstance(v, str) or not v):
            self.fail(key, f"expected a non-empty string, got {v!r}")
        return v

    def int(self, key, default=_REQUIRED, lo=None, hi=None, placeholder=None):
        v, done = self._get(key, default, placeholder)
        if done:
            return v
        if isinstance(v, bool) or not isinstance(v, int):
            self.fail(key, f"expected an integer, got {v!r}")
        return self._range(key, v, lo, hi, False)

    def float(self, key, default=_REQUIRED, lo=None, hi=None, lo_open=False):
        v, done = self._get(key, default, None)
        if done:
            return v
        if isinstance(v, bool) or not isinstance(v, (int, float)) or v != v or abs(v) == float("inf"):
            self.fail(key, f"expected a finite number, got {v!r}")
        return self._range(key, float(v), lo, hi, lo_open)

    def choice(self, key, options, default=_REQUIRED):
        v, done = self._get(key, default, None)
        if not done and (isinstance(v, bool) or v not in options):
            self.fail(key, f"{v!r} is not one of {', '.join(map(repr, options))}")
        return v

    def _list(self, key, length, default, scalar_ok, one):
        v, done = self._get(key, default, None)
        if done:
            return tuple(v) if v is not None else v
        if scalar_ok and not isinstance(v, list):
            v = [v] * length
        if not isinstance(v, list) or (length is not None and len(v) != length):
            self.fail(key, f"expected a list of {length or 'some'} values, got {v!r}")
        sub = KeyReader(dict(enumerate(v)), self.key(key), self.source, indexed=True)
        return tuple(one(sub, i) for i in range(len(v)))

    def int_list(self, key, length=None, lo=None, hi=None, default=_REQUIRED):
        return self._list(key, length, default, False, lambda s, i: s.int(i, lo=lo, hi=hi))

    def float_list(self, key, length=None, lo=None, lo_open=False, default=_REQUIRED,
                   scalar_ok=False):
        return self._list(key, length, default, scalar_ok,
                          lambda s, i: s.float(i, lo=lo, lo_open=lo_open))

    def table(self, key, required=True) -> "KeyReader | None":
        v, done = self._get(key, _REQUIRED if required else None, None)
        return None if done else KeyReader(v, self.key(key), self.source)

    def rest(self) -> dict:
        """Every key not read yet (and mark them read)."""
        out = {k: v for k, v in self.data.items() if k not in self._used}
        self._used.update(out)
        return out

    def finish(self) -> None:
        """ConfigError naming the first key that no getter asked for."""
        for k in self.data:
            if k not in self._used:
                self.fail(k, "unknown key")


# -- parsing --------------------------------------------------------------------------
def load_station_config(path: str | Path) -> StationConfig:
    """Read and parse a station TOML file; errors name ``path`` and the key."""
    path = Path(path)
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except OSError as e:
        raise ConfigError(f"cannot read: {e.strerror or e}", source=str(path)) from e
    except tomllib.TOMLDecodeError as e:
        raise ConfigError(f"not valid TOML: {e}", source=str(path)) from e
    return parse_station_config(data, str(path))


def parse_station_config(data: Mapping[str, Any], source: str | None = None) -> StationConfig:
    """Parse a TOML document (already a dict) into a :class:`StationConfig`."""
    top = KeyReader(data, "", source)
    robot = top.choice("robot", tuple(ROBOT_AXES))
    n = ROBOT_AXES[robot]
    unresolved: list[str] = []
    canopen = _canopen(top.table("canopen"), n, unresolved)
    incl = top.table("inclinometer", required=False)
    dw = top.table("drawwire", required=False)
    snap = top.table("snapshot", required=False)
    config = StationConfig(
        robot=robot, canopen=canopen,
        inclinometer=_inclinometer(incl, unresolved) if incl else None,
        drawwire=_drawwire(dw, unresolved) if dw else None,
        snapshot=_snapshot(snap) if snap else SnapshotConfig(),
        source=source, unresolved=tuple(unresolved))
    top.finish()
    return config


def _canopen(r: KeyReader, n: int, unresolved: list[str]) -> CanopenConfig:
    mode = r.choice("mode", ("cia402", "cia406"), default="cia402")
    nodes = r.int_list("nodes", length=n, lo=1, hi=127)
    if len(set(nodes)) != len(nodes):
        r.fail("nodes", "node ids must be distinct")
    hb = r.float("heartbeat_period", default=0.1, lo=0.0, lo_open=True)
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
        sdo_timeout=r.float("sdo_timeout", default=0.5, lo=0.0, lo_open=True),
        move_timeout=r.float("move_timeout", default=30.0, lo=0.0, lo_open=True),
        heartbeat_period=hb,
        heartbeat_timeout=r.float("heartbeat_timeout", default=5 * hb, lo=hb, lo_open=True),
        sync_period=r.float("sync_period", default=0.05, lo=0.0, lo_open=True))
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
                           offset_rad=a.float("offset_rad", default=0.0))
        a.finish()
    if not axes:
        r.fail("axes", "map at least one channel (tilt, roll or pitch)")
    axes_r.finish()
    cfg = InclinometerConfig(
        port=r.str("port", placeholder=unresolved), axes=frozen_map(axes),
        baudrate=r.int("baudrate", default=9600, lo=1, placeholder=unresolved),
        timeout=r.float("timeout", default=1.0, lo=0.0, lo_open=True))
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
        timeout=r.float("timeout", default=1.0, lo=0.0, lo_open=True))
    r.finish()
    return cfg


def _limits(r: KeyReader, key: str) -> Mapping[str, float]:
    t = r.table(key, required=False)
    if t is None:
        return frozen_map({})
    out = {}
    for ch in t.keys():
        if not LIMIT_CHANNEL.match(ch):
            t.fail(ch, "unknown channel (known: qm, qmN, tilt, roll, pitch, distance)")
        out[ch] = t.float(ch, lo=0.0)
    t.finish()
    return frozen_map(out)


def _snapshot(r: KeyReader) -> SnapshotConfig:
    cfg = SnapshotConfig(
        samples=r.int("samples", default=10, lo=1), period=r.float("period", default=0.02, lo=0.0),
        settle=r.float("settle", default=0.5, lo=0.0),
        timeout=r.float("timeout", default=1.0, lo=0.0, lo_open=True),
        std_limits=_limits(r, "std_limits"), drift_limits=_limits(r, "drift_limits"),
        noise_floor=_limits(r, "noise_floor"))
    r.finish()
    return cfg


# -- simulator endpoints ------------------------------------------------------------------
def load_json(path: str | Path):
    """A JSON file's content; unreadable or invalid files are ConfigErrors naming the file."""
    try:
        return json.loads(Path(path).read_text(encoding="utf-8"))
    except OSError as e:
        raise ConfigError(f"cannot read: {e.strerror or e}", source=str(path)) from e
    except json.JSONDecodeError as e:
        raise ConfigError(f"not valid JSON: {e}", source=str(path)) from e


def load_endpoints(path: str | Path) -> dict:
    """The endpoints JSON written by ``app.py simulate --endpoints FILE``."""
    data = load_json(path)
    if not isinstance(data, dict):
        raise ConfigError("expected a JSON object", source=str(path))
    return data


def with_endpoints(config: StationConfig, endpoints: Mapping[str, Any],
                   source: str = "endpoints") -> StationConfig:
    """A copy of ``config`` whose device addresses are those of the running simulator.

    ``endpoints`` as in cli.md: ``canopen`` {interface, host, port, channel, nodes},
    ``inclinometer`` {port, baudrate}, ``drawwire`` {host, port, device_id} (TCP) or
    {mode: "rtu", port: "/dev/pts/N", baudrate}; mode defaults to TCP where a host
    is given, else to the config's. Given values replace the config's
    (placeholder or not); keys this station does not know are ignored.
    """
    top = KeyReader(endpoints, "", source)
    unresolved = set(config.unresolved)
    changes: dict[str, Any] = {}

    def take(r: KeyReader, key: str, value, section: str, **to) -> None:
        name = to.get("field", key)
        if key in r.data:
            changes.setdefault(section, {})[name] = value(key)
            unresolved.discard(f"{section}.{name}")

    r = top.table("canopen", required=False)
    if r is not None:
        for k in ("interface", "channel", "host"):
            take(r, k, r.str, "canopen")
        take(r, "port", lambda k: r.int(k, lo=1, hi=65535), "canopen")
        n = len(config.canopen.nodes)
        take(r, "nodes", lambda k: r.int_list(k, length=n, lo=1, hi=127), "canopen")
    r = top.table("inclinometer", required=False)
    if r is not None and config.inclinometer is not None:
        take(r, "port", r.str, "inclinometer")
        take(r, "baudrate", lambda k: r.int(k, lo=1), "inclinometer")
    r = top.table("drawwire", required=False)
    if r is not None and config.drawwire is not None:
        guess = "tcp" if "host" in r.data else config.drawwire.mode
        if r.choice("mode", ("tcp", "rtu"), default=guess) == "rtu":
            changes["drawwire"] = {"mode": "rtu", "host": None, "port": None}
            unresolved -= {"drawwire.host", "drawwire.port"}
            take(r, "port", r.str, "drawwire", field="serial_port")
            take(r, "baudrate", lambda k: r.int(k, lo=1), "drawwire")
        else:
            changes["drawwire"] = {"mode": "tcp", "serial_port": None}
            unresolved.discard("drawwire.serial_port")
            take(r, "host", r.str, "drawwire")
            take(r, "port", lambda k: r.int(k, lo=1, hi=65535), "drawwire")
        take(r, "device_id", lambda k: r.int(k, lo=0, hi=247), "drawwire")
    sections = {k: dataclasses.replace(getattr(config, k), **v) for k, v in changes.items()}
    dw = sections.get("drawwire")
    for key in (("host", "port") if dw and dw.mode == "tcp" else ("serial_port",) if dw else ()):
        if getattr(dw, key) is None and f"drawwire.{key}" not in unresolved:
            raise ConfigError("missing required key (the drawwire mode changed)",
                              source=source, key=f"drawwire.{'port' if key == 'serial_port' else key}")
    return dataclasses.replace(config, **sections,
                               unresolved=tuple(k for k in config.unresolved if k in unresolved))
