"""Serial inclinometer with WitMotion-style binary frames (pyserial).

Wire format (the sensor's side: docs/real-station.md, "The inclinometer"): 11-byte frames
``55 TYPE d0L d0H d1L d1H d2L d2H d3L d3H SUM``, little-endian int16 data,
``SUM = sum(bytes 0..9) & 0xFF``.

- TYPE 0x53, angles: roll, pitch, yaw = raw / 32768 * 180 (deg); d3 unused.
- TYPE 0x51, acceleration: ax, ay, az = raw / 32768 * 16 (g); temperature = d3 / 100 (degC).

:class:`FrameParser` is a pure byte-stream parser; :class:`Inclinometer` reads a
port (path, or ``socket://host:port``) in a background thread and maps the raw
axes to the configured output channels (radians).
"""
from __future__ import annotations

import math
import struct
import threading
import time
from collections.abc import Mapping
from dataclasses import dataclass

import serial

from calibration.errors import ConfigError
from drivers.base import Device, Sample, log
from drivers.errors import DeviceError, DeviceTimeout

HEADER = 0x55
FRAME_LEN = 11
TYPE_ACCEL = 0x51
TYPE_ANGLES = 0x53
#: frame types a WitMotion-style sensor may send (time, accel, gyro, angles, mag, ...).
KNOWN_TYPES = frozenset(range(0x50, 0x5B))
AXES = ("roll", "pitch", "yaw")
_DATA = struct.Struct("<4h")


@dataclass(frozen=True)
class Frame:
    """One checksum-valid frame: ``type`` byte and its four raw int16 data words."""

    type: int
    data: tuple[int, int, int, int]

    @property
    def angles_deg(self) -> tuple[float, float, float]:
        """(roll, pitch, yaw) in degrees (TYPE 0x53)."""
        return tuple(v / 32768.0 * 180.0 for v in self.data[:3])

    @property
    def accel_g(self) -> tuple[float, float, float]:
        """(ax, ay, az) in g (TYPE 0x51)."""
        return tuple(v / 32768.0 * 16.0 for v in self.data[:3])

    @property
    def temperature_c(self) -> float:
        """Temperature in degC (TYPE 0x51)."""
        return self.data[3] / 100.0


def encode_frame(ftype: int, data: tuple[int, int, int, int]) -> bytes:
    """The 11 wire bytes of a frame; ``data`` are four int16 raw values."""
    body = bytes((HEADER, ftype)) + _DATA.pack(*data)
    return body + bytes((sum(body) & 0xFF,))


def _raw(value: float, full_scale: float) -> int:
    return max(-32768, min(32767, round(value / full_scale * 32768.0)))


def angles_frame(roll_deg: float, pitch_deg: float, yaw_deg: float) -> bytes:
    """A TYPE 0x53 frame for angles in degrees (wrapped into [-180, 180))."""
    wrap = [((a + 180.0) % 360.0) - 180.0 for a in (roll_deg, pitch_deg, yaw_deg)]
    return encode_frame(TYPE_ANGLES, (*(_raw(a, 180.0) for a in wrap), 0))


def accel_frame(ax_g: float, ay_g: float, az_g: float, temperature_c: float) -> bytes:
    """A TYPE 0x51 frame for accelerations in g and a temperature in degC."""
    return encode_frame(TYPE_ACCEL, (*(_raw(a, 16.0) for a in (ax_g, ay_g, az_g)),
                                     max(-32768, min(32767, round(temperature_c * 100.0)))))


class FrameParser:
    """Incremental parser: :meth:`feed` bytes in any chunking, get whole frames out.

    Never blocks. Bytes before a 0x55 header are skipped (``bytes_skipped``); a
    candidate frame with an unknown type or a wrong checksum is rejected
    (``checksum_errors`` counts the latter) and the search resumes one byte after
    its header, so a real frame hidden behind garbage is still found.
    """

    def __init__(self):
        self._buf = bytearray()
        self.frames_ok = 0
        self.checksum_errors = 0
        self.bytes_skipped = 0

    def feed(self, data: bytes) -> list[Frame]:
        """Add received bytes; return the frames completed by them, oldest first."""
        buf = self._buf
        buf += data
        frames: list[Frame] = []
        while True:
            start = buf.find(HEADER)
            if start < 0:
                self.bytes_skipped += len(buf)
                buf.clear()
                break
            if start:
                self.bytes_skipped += start
                del buf[:start]
            if len(buf) >= 2 and buf[1] not in KNOWN_TYPES:
                self.bytes_skipped += 1
                del buf[:1]
                continue
            if len(buf) < FRAME_LEN:
                break
            if sum(buf[:10]) & 0xFF != buf[10]:
                self.checksum_errors += 1
                self.bytes_skipped += 1
                del buf[:1]
                continue
            frames.append(Frame(buf[1], _DATA.unpack_from(buf, 2)))
            self.frames_ok += 1
            del buf[:FRAME_LEN]
        return frames

    @property
    def stats(self) -> dict[str, int]:
        return {"frames_ok": self.frames_ok, "checksum_errors": self.checksum_errors,
                "bytes_skipped": self.bytes_skipped}


class Inclinometer(Device):
    """A serial inclinometer; channels and mounting come from the station config.

    port:     serial device path (``/dev/ttyUSB0``, a pty slave) or ``socket://host:port``.
    axes:     output channel -> (raw axis ``roll``/``pitch``/``yaw``, sign +1/-1,
              offset in rad); channel value = sign * radians(raw axis) + offset.
              E.g. ``{"tilt": ("pitch", 1, 0.0)}`` or
              ``{"roll": ("roll", 1, 0.0), "pitch": ("pitch", 1, 0.0)}``.
    baudrate: bit/s (8N1), 9600 by default.
    timeout:  s that :meth:`read` waits for a fresh angle frame.
    """

    def __init__(self, port: str, axes: Mapping[str, tuple], *, baudrate: int = 9600,
                 timeout: float = 1.0, name: str | None = None):
        super().__init__(name or f"inclinometer {port}", timeout)
        self.port = port
        self.baudrate = int(baudrate)
        self.axes = self._check_axes(axes)
        self.channels = tuple(self.axes)
        self.parser = FrameParser()
        self._serial = None
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self._cond = threading.Condition()
        self._seq = 0
        self._last_read_seq = 0
        self._latest: Sample | None = None
        self._extra: dict = {}
        self._error: BaseException | None = None

    @staticmethod
    def _check_axes(axes: Mapping[str, tuple]) -> dict[str, tuple[int, float, float]]:
        if not axes:
            raise ConfigError("at least one output channel is required", key="axes")
        out = {}
        for ch, spec in axes.items():
            try:
                axis, sign, offset = spec
            except (TypeError, ValueError):
                raise ConfigError(f"expected (axis, sign, offset_rad), got {spec!r}",
                                  key=f"axes.{ch}") from None
            if axis not in AXES:
                raise ConfigError(f"axis {axis!r} is not one of {AXES}", key=f"axes.{ch}")
            if sign not in (1, -1):
                raise ConfigError(f"sign must be +1 or -1, got {sign!r}", key=f"axes.{ch}")
            if not math.isfinite(float(offset)):
                raise ConfigError(f"offset must be finite, got {offset!r}", key=f"axes.{ch}")
            out[str(ch)] = (AXES.index(axis), float(sign), float(offset))
        return out

    @property
    def stats(self) -> dict[str, int]:
        """Parser counters: frames_ok, checksum_errors, bytes_skipped."""
        return self.parser.stats

    # -- hooks ------------------------------------------------------------------
    def _open_internal(self) -> None:
        try:
            self._serial = serial.serial_for_url(
                self.port, baudrate=self.baudrate, bytesize=serial.EIGHTBITS,
                parity=serial.PARITY_NONE, stopbits=serial.STOPBITS_ONE, timeout=0.05)
            self._serial.reset_input_buffer()
        except (serial.SerialException, OSError, ValueError) as e:
            raise DeviceError(f"cannot open serial port {self.port}: {e}", device=self.name) from e
        self._stop.clear()
        self._error = None
        self._thread = threading.Thread(target=self._reader, name=f"{self.name} reader",
                                        daemon=True)
        self._thread.start()

    def _close_internal(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
            self._thread = None
        if self._serial is not None:
            self._serial.close()
            self._serial = None

    def discard_pending(self) -> None:
        """Forget the frames received so far: the next read waits for a frame received
        after now (a snapshot after a move must not take a frame of the moving robot)."""
        with self._cond:
            self._last_read_seq = self._seq

    def _read_internal(self, timeout: float) -> Sample:
        end = time.monotonic() + timeout
        with self._cond:
            while self._seq <= self._last_read_seq:
                if self._error is not None:
                    raise DeviceError(f"serial port {self.port} failed: {self._error}",
                                      device=self.name) from self._error
                left = end - time.monotonic()
                if left <= 0:
                    raise DeviceTimeout(
                        f"no valid angle frame on {self.port} within {timeout:g} s "
                        f"(checksum errors so far: {self.parser.checksum_errors})",
                        device=self.name)
                self._cond.wait(left)
            self._last_read_seq = self._seq
            return self._latest

    # -- background reader -------------------------------------------------------
    def _reader(self) -> None:
        ser = self._serial
        try:
            while not self._stop.is_set():
                data = ser.read(max(1, ser.in_waiting))
                if data:
                    self._handle(self.parser.feed(data))
        except (serial.SerialException, OSError) as e:
            if not self._stop.is_set():
                log.error("%s: reading %s failed: %s", self.name, self.port, e)
                with self._cond:
                    self._error = e
                    self._cond.notify_all()

    def _handle(self, frames: list[Frame]) -> None:
        for fr in frames:
            if fr.type == TYPE_ACCEL:
                self._extra = {"accel_g": fr.accel_g, "temperature_c": fr.temperature_c}
            elif fr.type == TYPE_ANGLES:
                raw = fr.angles_deg
                values = {ch: sign * math.radians(raw[i]) + off
                          for ch, (i, sign, off) in self.axes.items()}
                with self._cond:
                    self._seq += 1
                    self._latest = Sample(time.monotonic(), values, self._seq,
                                          {"raw_deg": raw, **self._extra})
                    self._cond.notify_all()
