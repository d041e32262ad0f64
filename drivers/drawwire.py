"""Draw-wire distance sensor over Modbus RTU or TCP (pymodbus 3.16 sync clients).

Register map (holding registers, function codes 03 and 06 only):

====== ============================================================
0x0000 position count, UINT32 over two registers (word order configurable,
0x0001 high word first by default)
0x0002 turns of the drum
0x0008 write 1: zero the count at the current position
====== ============================================================

distance (m) = count * metres_per_count + offset_m, where the UINT32 count is read
as two's complement: a count below the zero point (the cable pulled in past the
position where it was zeroed, or noise right at it) wraps to 2**32 - n on the
wire and means -n; no draw-wire cable is 2**31 counts long.
"""
from __future__ import annotations

import time

from pymodbus.client import ModbusSerialClient, ModbusTcpClient
from pymodbus.exceptions import ConnectionException, ModbusException, ModbusIOException
from pymodbus.pdu import ExceptionResponse

from calibration.errors import ConfigError
from drivers.base import Device, Sample, log
from drivers.errors import DeviceError, DeviceTimeout, ProtocolError

#: station-config word order (``drawwire.word_order``) -> this driver's ``word_order``
WORD_ORDER = {"high-first": "big", "low-first": "little"}

REG_COUNT = 0x0000
REG_TURNS = 0x0002
REG_ZERO = 0x0008

#: Modbus exception codes and their meaning (Modbus Application Protocol v1.1b3, 7).
EXCEPTION_TEXT = {
    0x01: "illegal function",
    0x02: "illegal data address",
    0x03: "illegal data value",
    0x04: "server device failure",
    0x05: "acknowledge",
    0x06: "server device busy",
    0x07: "negative acknowledge",
    0x08: "memory parity error",
    0x0A: "gateway path unavailable",
    0x0B: "gateway target device failed to respond",
}


def combine_words(regs: list[int], word_order: str) -> int:
    """UINT32 from two 16-bit registers; ``word_order`` ``"big"`` = high word first."""
    hi, lo = (regs[0], regs[1]) if word_order == "big" else (regs[1], regs[0])
    return (hi << 16) | lo


def split_words(value: int, word_order: str) -> list[int]:
    """Two 16-bit registers of a UINT32 (inverse of :func:`combine_words`)."""
    value &= 0xFFFFFFFF
    hi, lo = value >> 16, value & 0xFFFF
    return [hi, lo] if word_order == "big" else [lo, hi]


class DrawWire(Device):
    """A Modbus draw-wire sensor; channel ``distance`` (m).

    port:             serial device or pty path for RTU (exclusive with ``host``).
    host, tcp_port:   Modbus TCP server address.
    metres_per_count: wire travel per count (m).
    offset_m:         cable length at count 0 (m).
    device_id:        Modbus device address (1).
    word_order:       ``"big"`` (high word first, default) or ``"little"``.
    baudrate:         RTU bit/s (8N1).
    timeout:          s per request before :class:`DeviceTimeout`.
    retries, backoff_s: reconnect attempts after a dropped link, first delay
                      (doubled each attempt).

    ``reconnects`` counts links re-established after a failure.
    """

    channels = ("distance",)

    def __init__(self, *, metres_per_count: float, offset_m: float = 0.0,
                 port: str | None = None, host: str | None = None, tcp_port: int = 502,
                 device_id: int = 1, word_order: str = "big", baudrate: int = 19200,
                 parity: str = "N", stopbits: int = 1, timeout: float = 1.0, retries: int = 3, backoff_s: float = 0.05,
                 name: str | None = None):
        if (port is None) == (host is None):
            raise ConfigError("give exactly one of port (RTU) or host (TCP)", key="drawwire")
        if word_order not in ("big", "little"):
            raise ConfigError(f"must be 'big' or 'little', got {word_order!r}",
                              key="drawwire.word_order")
        if not metres_per_count > 0:
            raise ConfigError(f"must be > 0, got {metres_per_count!r}",
                              key="drawwire.metres_per_count")
        self.where = port if port is not None else f"{host}:{tcp_port}"
        super().__init__(name or f"draw-wire {self.where}", timeout)
        self.metres_per_count = float(metres_per_count)
        self.offset_m = float(offset_m)
        self.device_id = int(device_id)
        self.word_order = word_order
        self.retries = int(retries)
        self.backoff_s = float(backoff_s)
        self.reconnects = 0
        self._link_lost = False
        self._seq = 0
        if port is not None:
            if parity not in ("N", "E", "O") or stopbits not in (1, 2):
                raise ConfigError(f"parity must be N, E or O and stopbits 1 or 2, got "
                                  f"{parity!r}, {stopbits!r}", key="drawwire")
            self._client = ModbusSerialClient(port, baudrate=baudrate, bytesize=8, parity=parity,
                                              stopbits=int(stopbits), timeout=self.timeout,
                                              retries=0)
        else:
            self._client = ModbusTcpClient(host, port=int(tcp_port), timeout=self.timeout,
                                           retries=0)
        self._tcp = host is not None

    # -- public -------------------------------------------------------------------
    def zero(self) -> None:
        """Zero the count at the current position (write 1 to 0x0008, function 06)."""
        if not self.is_open:
            raise DeviceError("device is not open", device=self.name)
        self._request("write_register", REG_ZERO, 1, timeout=self.timeout)
        log.info("%s: zeroed", self.name)

    # -- hooks ----------------------------------------------------------------------
    def _open_internal(self) -> None:
        if not self._client.connect():
            what = "connect to Modbus TCP server" if self._tcp else "open serial port"
            raise DeviceError(f"cannot {what} {self.where}", device=self.name)

    def _close_internal(self) -> None:
        self._client.close()

    def _read_internal(self, timeout: float) -> Sample:
        since = time.monotonic()     # the sensor reads its count between the request and t
        regs = self._request("read_holding_registers", REG_COUNT, timeout=timeout, count=3)
        count = combine_words(regs[:2], self.word_order)
        if count >= 1 << 31:        # below the zero point (module docstring)
            count -= 1 << 32
        distance = count * self.metres_per_count + self.offset_m
        self._seq += 1
        return Sample(time.monotonic(), {"distance": distance}, self._seq,
                      {"count": count, "turns": regs[2], "since": since})

    # -- one request with recovery --------------------------------------------------------
    def _request(self, method: str, address: int, *args, timeout: float, **kw) -> list[int]:
        """Run one client request; decode exceptions; reconnect a dropped link."""
        self._client.comm_params.timeout_connect = timeout
        last: Exception | None = None
        for attempt in range(self.retries + 1):
            if attempt:
                delay = self.backoff_s * 2 ** (attempt - 1)
                log.warning("%s: link lost (%s), reconnect %d/%d in %.2f s",
                            self.name, last, attempt, self.retries, delay)
                time.sleep(delay)
            try:
                if not self._client.connect():
                    raise ConnectionException(f"cannot connect to {self.where}")
                resp = getattr(self._client, method)(address, *args, device_id=self.device_id, **kw)
            except (ConnectionException, OSError) as e:   # OSError: reset while receiving
                self._client.close()
                self._link_lost = True
                last = e
                continue
            except ModbusIOException as e:
                if self._tcp:      # a late answer must not be taken for the next one
                    self._client.close()
                raise DeviceTimeout(f"no answer from {self.where} within {timeout:g} s "
                                    f"({method} 0x{address:04X})", device=self.name) from e
            except ModbusException as e:
                raise DeviceError(f"{method} 0x{address:04X} failed: {e}", device=self.name) from e
            if self._link_lost:
                self._link_lost = False
                self.reconnects += 1
                log.warning("%s: link to %s recovered (reconnects=%d)",
                            self.name, self.where, self.reconnects)
            if isinstance(resp, ExceptionResponse) or resp.isError():
                code = getattr(resp, "exception_code", None)
                text = EXCEPTION_TEXT.get(code, "unknown exception")
                raise ProtocolError(f"{method} 0x{address:04X} answered with an exception",
                                    code=code, text=text, device=self.name)
            return list(resp.registers)
        raise DeviceError(f"link to {self.where} down after {self.retries} reconnect "
                          f"attempt(s): {last}", device=self.name) from last
