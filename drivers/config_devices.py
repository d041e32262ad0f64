"""The station config's wired-device sections: the actuators' CANopen bus, the serial
inclinometer and the Modbus draw-wire, each a frozen dataclass and its reader.

::

    [canopen]        interface, channel, host, port, nodes, increments_per_unit, mode,
                     profile_velocity, profile_acceleration, sdo_timeout, move_timeout,
                     heartbeat_period, heartbeat_timeout, sync_period
    [canopen.bus]    further python-can keyword arguments (bitrate, ...)
    [inclinometer]   port (device or pyserial URL), baudrate, timeout
    [inclinometer.axes]  channel = { raw = "pitch", sign = 1, offset_rad = 0.0, range_rad = 1.05 }
                     (range_rad optional: the sensor reads |value| up to it)
    [drawwire]       mode "tcp" | "rtu", host/port or serial_port, device_id, ...

Parsed by :func:`_canopen`, :func:`_inclinometer` and :func:`_drawwire` with
:class:`~drivers.config_reader.KeyReader` (errors name the file and the key path,
``drawwire.port: expected an integer``); ``unresolved`` collects the keys still holding
``"@endpoints"``. Builds on :mod:`drivers.config_reader` only, so :mod:`drivers.config`
(the whole station config, which re-exports these names) can import it; the motion
capture's ``[mocap]`` is :mod:`drivers.config_mocap`. Units: SI, radians, seconds.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from types import MappingProxyType
from typing import Any, Mapping

from drivers.config_reader import (MAX_MOVE_S, MAX_PERIOD_S, MAX_TIMEOUT_S, KeyReader,
                                   frozen_map)

INCLINOMETER_CHANNELS = ("tilt", "roll", "pitch", "yaw")
RAW_AXES = ("roll", "pitch", "yaw")


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
