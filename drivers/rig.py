"""The station's devices, built from one :class:`~drivers.config.StationConfig`.

:class:`Rig` owns the actuators (CANopen drives or encoders), the inclinometer,
the draw-wire and the motion capture of a station, opens and closes them together, and
offers the few operations a session needs: move and wait, one live reading of every
channel, one checked snapshot of a pose, zeroing the draw-wire. The session and
``app.py devices check`` use it; nothing here knows a method or a widget.
"""
from __future__ import annotations

import dataclasses
import logging
import math
import time
from datetime import datetime, timezone
from typing import Any, Mapping, Sequence

from drivers.base import Device, Sample
from drivers.canopen_drives import CanopenActuators, CanopenNodes, canopen_device
from drivers.config import StationConfig
from drivers.drawwire import WORD_ORDER, DrawWire
from drivers.errors import DeviceError
from drivers.inclinometer import Inclinometer
from drivers.mocap import AXES, MotionCapture
from drivers.snapshot import Snapshot, UnstableReading, snapshot_with

log = logging.getLogger("drivers.rig")

#: times an unstable snapshot is taken again before it is the device's fault
SETTLE_RETAKES = 3
#: s of the first wait before a retake (at least the config's settle); each next doubles
RESETTLE_S = 0.1


def retake_waits(settle: float) -> list[float]:
    """The waits (s) before each retake of an unstable snapshot: ``max(RESETTLE_S,
    settle)`` doubled each time (0.1, 0.2, 0.4 s at a test settle of 10 ms; 0.5, 1, 2 s
    at the default 0.5 s)."""
    first = max(RESETTLE_S, float(settle))
    return [first * 2 ** k for k in range(SETTLE_RETAKES)]


def inclinometer_from_config(cfg) -> Inclinometer:
    """The inclinometer an :class:`~drivers.config.InclinometerConfig` describes (not opened)."""
    axes = {ch: (a.raw, a.sign, a.offset_rad) for ch, a in cfg.axes.items()}
    return Inclinometer(cfg.port, axes, baudrate=cfg.baudrate, timeout=cfg.timeout,
                        name="inclinometer")


def drawwire_from_config(cfg) -> DrawWire:
    """The draw-wire a :class:`~drivers.config.DrawwireConfig` describes (not opened)."""
    kw = dict(metres_per_count=cfg.metres_per_count, offset_m=cfg.offset_m,
              device_id=cfg.device_id, word_order=WORD_ORDER[cfg.word_order],
              timeout=cfg.timeout, name="draw-wire")
    if cfg.mode == "tcp":
        return DrawWire(host=cfg.host, tcp_port=cfg.port, **kw)
    return DrawWire(port=cfg.serial_port, baudrate=cfg.baudrate, parity=cfg.parity,
                    stopbits=cfg.stopbits, **kw)


def mocap_from_config(cfg) -> MotionCapture:
    """The motion capture a :class:`~drivers.config_mocap.MocapConfig` describes (not opened)."""
    return MotionCapture(cfg.host, port=cfg.port, labels=cfg.labels, frames=cfg.frames,
                         timeout=cfg.timeout, name="motion capture")


@dataclasses.dataclass(frozen=True)
class PoseSnapshot(Snapshot):
    """A :class:`~drivers.snapshot.Snapshot` with ``info``: device name -> what its reading
    says beyond the means (the motion capture: ``frames``, ``timestamps_us``, ``seen``,
    ``std``, ``drift`` of :mod:`drivers.mocap`)."""

    info: Mapping[str, Any] = dataclasses.field(default_factory=dict)


def with_mocap(snap: Snapshot, mocap: MotionCapture, sample: Sample) -> PoseSnapshot:
    """``snap`` with one reading of the motion capture (the mean of its N frames): each
    marker's mean, std and drift over the frames it was seen in; a marker seen in fewer
    than half of them is NaN (its count is in ``info``). ``t_end`` and ``duration`` then
    include the motion capture's read, taken right after the others'."""
    n = len(sample.info["frames"])
    mean, std, drift = dict(snap.mean), dict(snap.std), dict(snap.drift)
    devices = dict(snap.devices or {})
    for k, label in enumerate(mocap.labels, start=1):
        enough = 2 * sample.info["seen"][label] >= n
        for a, axis in enumerate(AXES):
            ch = f"m{k}_{axis}"
            mean[ch] = sample.values[ch] if enough else math.nan
            std[ch] = sample.info["std"][label][a] if enough else math.nan
            drift[ch] = sample.info["drift"][label][a] if enough else math.nan
            devices[ch] = mocap.name
    fields = {f.name: getattr(snap, f.name) for f in dataclasses.fields(Snapshot)}
    fields.update(mean=mean, std=std, drift=drift, devices=devices,
                  t_end=datetime.now(timezone.utc).isoformat(timespec="milliseconds"),
                  duration=snap.duration + (sample.t - sample.info["since"]))
    info = dict(getattr(snap, "info", {}))
    info[mocap.name] = {k: v for k, v in sample.info.items() if k != "since"}
    return PoseSnapshot(**fields, info=info)


class Rig:
    """Every device of a station (config resolved: no ``"@endpoints"`` left).

    ``actuators`` is a :class:`CanopenActuators` (the station moves the robot) or
    :class:`~drivers.canopen_drives.CanopenEncoders` (read only); ``inclinometer``,
    ``drawwire`` and ``mocap`` are None where the station has none.
    """

    mocap: MotionCapture | None = None

    def __init__(self, config: StationConfig):
        self.config = config.require_resolved()
        self.actuators: CanopenNodes = canopen_device(config.canopen)
        self.inclinometer = (inclinometer_from_config(config.inclinometer)
                             if config.inclinometer is not None else None)
        self.drawwire = (drawwire_from_config(config.drawwire)
                         if config.drawwire is not None else None)
        self.mocap = mocap_from_config(config.mocap) if config.mocap is not None else None

    @property
    def devices(self) -> list[Device]:
        return [d for d in (self.actuators, self.inclinometer, self.drawwire, self.mocap)
                if d is not None]

    @property
    def can_move(self) -> bool:
        return isinstance(self.actuators, CanopenActuators)

    # -- lifecycle -------------------------------------------------------------------------
    def open(self) -> "Rig":
        """Open every device (drives are enabled); on a failure, close those already
        opened and raise the device's error."""
        opened = []
        try:
            for d in self.devices:
                d.open()
                opened.append(d)
            if self.can_move:
                self.actuators.enable(self.config.canopen.sdo_timeout * 4)
        except BaseException:
            for d in reversed(opened):
                _close_quietly(d)
            raise
        return self

    def close(self) -> None:
        for d in reversed(self.devices):
            _close_quietly(d)

    def __enter__(self):
        return self.open()

    def __exit__(self, *exc):
        self.close()

    # -- readings --------------------------------------------------------------------------
    def read(self) -> dict[str, float]:
        """One fresh reading of every channel of every device."""
        values: dict[str, float] = {}
        for d in self.devices:
            values.update(d.read().values)
        return values

    def read_timed(self, actuators_only: bool = False) -> dict[str, tuple[float, float, float]]:
        """One fresh reading of every channel with the interval it was sampled in:
        channel -> ``(value, since, until)`` (``time.monotonic()``). A polled device's
        values were sampled between its request and its answer, the actuators' at the
        SYNC they answered; a streaming device's frame (the inclinometer) up to the
        ``[envelope] latency`` before it was received (its output period, filter and
        transmission). With ``actuators_only``, only the actuators."""
        out: dict[str, tuple[float, float, float]] = {}
        for d in ([self.actuators] if actuators_only else self.devices):
            s = d.read()
            since = s.info.get("since")
            if since is None:
                since = s.t - self.config.envelope.latency
            out.update({ch: (v, float(since), s.t) for ch, v in s.values.items()})
        return out

    def discard_pending(self) -> None:
        """The streaming sensors' next readings are frames received after now."""
        if self.inclinometer is not None:
            self.inclinometer.discard_pending()

    def qm(self) -> list[float]:
        s = self.actuators.read()
        return [s.values[ch] for ch in self.actuators.channels]

    def snapshot(self, on_retake=None, **overrides) -> Snapshot:
        """One checked measurement of the current pose with the configured settle,
        samples and limits (:func:`drivers.snapshot.snapshot_with`). Readings not yet
        stable (:class:`~drivers.snapshot.UnstableReading`: the arm or a sensor's filter
        still settling after the move, a streaming sensor's frames queued behind a busy
        computer) are measured again after a wait, :data:`SETTLE_RETAKES` times at most
        (:func:`retake_waits`); ``on_retake(error, wait_s)`` is told before each wait.
        Still unstable after the last: that UnstableReading, the device's fault.
        The motion capture averages its N frames itself: it is read once, after the
        others, and its means join theirs (:func:`with_mocap`, a :class:`PoseSnapshot`)."""
        waits = retake_waits(overrides.get("settle", self.config.snapshot.settle))
        sensors = [d for d in self.devices if d is not self.mocap]
        while True:
            try:
                snap = snapshot_with(sensors, self.config.snapshot, **overrides)
                return snap if self.mocap is None else with_mocap(snap, self.mocap,
                                                                  self.mocap.read())
            except UnstableReading as e:
                if not waits:
                    raise
                wait = waits.pop(0)
                if on_retake is not None:
                    on_retake(e, wait)
                time.sleep(wait)

    # -- motion ----------------------------------------------------------------------------
    def move_to(self, qm: Sequence[float], timeout: float | None = None) -> None:
        """Move every actuator to ``qm`` (actuator units) and wait for target reached."""
        t = self.config.canopen.move_timeout if timeout is None else timeout
        t0 = time.monotonic()
        self.start_move(qm)
        self.wait_moved(max(0.1, t - (time.monotonic() - t0)))

    def start_move(self, qm: Sequence[float]) -> None:
        """Start a move of every actuator to ``qm`` and return at once (the drives
        acknowledged the set-point); :meth:`wait_moved` waits for target reached."""
        self._movable().move_to(qm, timeout=self.config.canopen.sdo_timeout * 4)

    def slower(self, factor: float):
        """A block whose moves run at ``factor`` of the drives' profile velocity
        (:meth:`drivers.canopen_drives.CanopenActuators.slower`)."""
        return self._movable().slower(factor)

    def _movable(self) -> CanopenActuators:
        """The drives; DeviceError where the station only reads encoders."""
        if not self.can_move:
            raise DeviceError("the actuators are read-only encoders (canopen.mode = "
                              "\"cia406\"): move the robot with its own controller",
                              device=self.actuators.name)
        return self.actuators

    def wait_moved(self, timeout: float | None = None) -> None:
        """Wait until every drive reports target reached."""
        self.actuators.wait_target_reached(self.config.canopen.move_timeout if timeout is None
                                           else timeout)

    def stop(self) -> None:
        """Stop where the robot is now: a new set-point at the actuator values read now
        (applied immediately), then wait for it."""
        self.start_move(self.qm())
        self.wait_moved()

    def fault_reset(self) -> None:
        if self.can_move:
            self.actuators.fault_reset(self.config.canopen.sdo_timeout * 4)

    def zero_drawwire(self) -> None:
        if self.drawwire is None:
            raise DeviceError("this station has no draw-wire ([drawwire] in the station "
                              "config)", device="draw-wire")
        self.drawwire.zero()

    def recover(self) -> str:
        """After a failed measurement: reset the drives that report FAULT (statusword
        bit 3); where none does, or they cannot be asked, close and reopen every device
        (a re-plugged cable, a dropped link). Returns what it did, in words."""
        if self.can_move and self.actuators.is_open:
            try:
                faulted = [n for n in self.actuators.nodes
                           if self.actuators.statusword(n) & 0x0008]
            except DeviceError:
                faulted = []
            if faulted:
                self.fault_reset()
                return f"fault reset (nodes {faulted})"
        time.sleep(0.2)
        self.reconnect()
        return "reconnected"

    def reconnect(self) -> None:
        """Close and open every device again (after a cable was re-plugged)."""
        self.close()
        self.open()


def _close_quietly(d: Device) -> None:
    try:
        d.close()
    except Exception as e:  # a device that is gone cannot be closed cleanly
        log.warning("%s: close failed: %s", d.name, e)
