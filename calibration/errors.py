"""The one exception root of the station, and the errors of its numerics and inputs.

Every error the station raises on purpose derives from :class:`StationError`, so
that the command line and the GUI can catch one class and print one line.
Device errors live in :mod:`drivers.errors` and derive from the same root.
"""
from __future__ import annotations


class StationError(Exception):
    """Root of every error the station raises on purpose (a user or device error)."""


class ConfigError(StationError, ValueError):
    """A configuration, robot model or truth file is invalid; the message names the key."""

    def __init__(self, message: str, *, source: str | None = None, key: str | None = None):
        self.source = source
        self.key = key
        where = ": ".join(p for p in (source, key) if p)
        super().__init__(f"{where}: {message}" if where else message)


class TraceFormatError(StationError, ValueError):
    """A trace or parameter file is malformed; carries the file and (1-based) line."""

    def __init__(self, message: str, *, file: str | None = None, line: int | None = None):
        self.file = file
        self.line = line
        where = file or "<trace>"
        if line is not None:
            where = f"{where}:{line}"
        super().__init__(f"{where}: {message}")


class CalibrationError(StationError):
    """The data cannot support a calibration (too few poses, non-finite values, ...)."""


class UnreachablePose(CalibrationError):
    """Inverse kinematics has no solution for the requested pose."""
