"""Device errors: all derive from :class:`calibration.errors.StationError`."""
from __future__ import annotations

from calibration.errors import StationError


class DeviceError(StationError):
    """A device failed or answered wrongly; ``device`` names it (e.g. ``canopen node 3``)."""

    def __init__(self, message: str, *, device: str | None = None):
        self.device = device
        super().__init__(f"{device}: {message}" if device else message)


class DeviceTimeout(DeviceError, TimeoutError):
    """A device did not answer (or stopped talking) within its timeout."""


class ProtocolError(DeviceError):
    """A device answered with a protocol-level error; carries its code and text."""

    def __init__(self, message: str, *, code: int | None = None, text: str | None = None,
                 device: str | None = None):
        self.code = code
        self.text = text
        detail = message
        if code is not None:
            detail += f" (code 0x{code:X}" + (f": {text})" if text else ")")
        super().__init__(detail, device=device)
