"""A device that is gone: told apart from a fault of one pose, and named.

A pose fails (:class:`~drivers.errors.DeviceError`); the session retries it after
a growing pause (:func:`backoff`: a short outage, a re-plugged cable, a drive reset)
and, when the fault policy gives up on the pose, asks :func:`probe` whether the
device itself still answers: recover the rig (reset or reconnect) and read the
failing device once where the robot stands. If it answers, the fault belonged to
that pose (skipped; measured again on resume). If it does not (a silent CANopen
node, the simulator or a cable gone, a persistent Modbus exception, a silent
inclinometer), every further pose would fail the same way: the session stops at
once with :class:`DeviceLost`, which names the device and what to check, and the
poses not measured stay pending for the resume once the fault is cleared.
"""
from __future__ import annotations

from calibration.errors import StationError
from drivers.check import hint_for
from drivers.errors import DeviceError

BACKOFF_S = (0.25, 0.5, 1.0, 2.0)      # pauses before retries 1, 2, 3, 4 (then 2 s)


class DeviceLost(StationError):
    """A device stopped answering for good; ``device`` names it."""

    def __init__(self, error: DeviceError, simulated: bool = False):
        self.device = error.device or "a device"
        self.error = error
        detail = str(error)
        if error.device and detail.startswith(f"{error.device}: "):
            detail = detail[len(error.device) + 2:]
        super().__init__(f"{self.device} does not answer ({detail}): {hint_for(self.device, simulated)}. "
                         "The session stopped; the trace is intact: once the device answers "
                         "again, run the session again to measure the remaining poses")


def backoff(attempt: int) -> float:
    """The pause (s) before retry ``attempt`` (1-based)."""
    return BACKOFF_S[min(max(attempt, 1), len(BACKOFF_S)) - 1]


def not_connected(rig) -> DeviceError | None:
    """A DeviceError naming the rig's devices that are closed (a reconnect failed)."""
    closed = [d.name for d in rig.devices if not d.is_open]
    if not closed:
        return None
    return DeviceError("not connected (its reconnection failed)", device=closed[0])


def _device(rig, name: str | None):
    """The rig's device that raised an error naming ``name`` (None: not one of them)."""
    for d in rig.devices:
        if name and (name == d.name or name.startswith(d.name)):
            return d
    return None


def probe(rig, error: DeviceError, simulated: bool = False) -> DeviceLost | None:
    """After a pose failed with ``error``: recover the rig and read the failing device
    (every device when the error names none). None if it answers, else DeviceLost."""
    try:
        rig.recover()
    except DeviceError as e:
        return DeviceLost(e, simulated)
    dev = _device(rig, error.device)
    try:
        for d in [dev] if dev is not None else rig.devices:
            d.read()
    except DeviceError as e:
        return DeviceLost(e, simulated)
    return None
