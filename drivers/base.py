"""The small interface every device driver implements (house style 1).

As in python-can's ``BusABC``: the public methods own the common behaviour
(open state, timeouts, validation, logging, idempotent close, context manager);
a driver overrides only the ``_..._internal`` hooks.

Channels are named, SI units, radians:
``qm1..qmN`` (actuator units of ``Q = K*Qm + Q_off``), ``tilt`` (SM ``phi``),
``roll``/``pitch`` (a dual-axis inclinometer's physical angles), ``distance`` (m).
"""
from __future__ import annotations

import logging
import math
from abc import ABC, abstractmethod
from dataclasses import dataclass, field

from drivers.errors import DeviceError

log = logging.getLogger("drivers")


@dataclass(frozen=True)
class Sample:
    """One reading of a device: ``values`` channel -> value, taken at ``t``
    (``time.monotonic()`` of reception); ``seq`` increases with every fresh datum
    from the device, so that a repeated (stale) datum can be told from a new one.
    ``info["since"]`` where the driver knows it: the earliest time the values can have
    been sampled (a polled device: when the request went out; CANopen: the SYNC), so
    that they were sampled in ``[since, t]``. A streaming device (the inclinometer)
    does not know it: its frames are up to a known latency old when received."""

    t: float
    values: dict[str, float]
    seq: int = 0
    info: dict = field(default_factory=dict)


class Device(ABC):
    """A device the station reads (and perhaps commands).

    name:    how errors and logs name it (``"inclinometer"``, ``"canopen node 3"``).
    timeout: seconds a single read may take before :class:`DeviceTimeout`.
    """

    channels: tuple[str, ...] = ()
    #: a NaN reading is a value the device did not see (a motion capture's occluded
    #: marker), not a fault; every other device's NaN is one
    unseen_is_nan: bool = False

    def __init__(self, name: str, timeout: float = 1.0):
        self.name = name
        self.timeout = float(timeout)
        self._is_open = False

    # -- lifecycle ------------------------------------------------------------
    def open(self) -> "Device":
        if not self._is_open:
            log.info("%s: opening", self.name)
            self._open_internal()
            self._is_open = True
        return self

    def close(self) -> None:
        if self._is_open:
            self._is_open = False
            try:
                self._close_internal()
            finally:
                log.info("%s: closed", self.name)

    @property
    def is_open(self) -> bool:
        return self._is_open

    def __enter__(self):
        return self.open()

    def __exit__(self, *exc):
        self.close()

    # -- reading ----------------------------------------------------------------
    def read(self, timeout: float | None = None) -> Sample:
        """One fresh sample of every channel; raises DeviceTimeout / DeviceError."""
        if not self._is_open:
            raise DeviceError("device is not open", device=self.name)
        sample = self._read_internal(self.timeout if timeout is None else float(timeout))
        for ch, v in sample.values.items():
            if not isinstance(v, (int, float)) or math.isinf(v) or (
                    math.isnan(v) and not self.unseen_is_nan):
                raise DeviceError(f"channel {ch!r} gave a non-finite value {v!r}", device=self.name)
        return sample

    # -- hooks ------------------------------------------------------------------
    @abstractmethod
    def _open_internal(self) -> None: ...

    @abstractmethod
    def _close_internal(self) -> None: ...

    @abstractmethod
    def _read_internal(self, timeout: float) -> Sample: ...
