"""Writing a trace (docs/file-formats.md): :class:`TraceWriter` appends one record per
line and flushes and fsyncs each, so a crash loses at most the line being written;
:func:`write_trace` writes a whole trace at once, atomically."""
from __future__ import annotations

import json
import os
import warnings
from pathlib import Path

from calibration.errors import ConfigError, StationError
from drivers.atomic import write_atomic
from station.recording.trace import (FORMAT, VERSION, Trace, TruncatedLineWarning, read_trace,
                                     utc_now)


def _line(rec: dict) -> bytes:
    return (json.dumps(rec, separators=(",", ":"), allow_nan=False) + "\n").encode("utf-8")


def _header_record(header: dict) -> dict:
    rec = {"record": "header", "format": FORMAT, "version": VERSION, "created": utc_now()}
    rec.update(header)
    return rec


class TraceWriter:
    """Appends records to a trace: one line each, flushed and fsynced.

    ``TraceWriter.create(path, header)`` starts a new trace (refuses to
    overwrite); ``TraceWriter.resume(path)`` reopens one, cutting a truncated
    last line, and reports what is already recorded.
    """

    def __init__(self, path: str, fh, trace: Trace | None = None):
        self.path = path
        self._fh = fh
        self.trace = trace
        self._failed: StationError | None = None

    @classmethod
    def create(cls, path, header: dict) -> "TraceWriter":
        path = str(path)
        rec = _header_record(header)
        try:
            fh = open(path, "xb")
        except FileExistsError:
            raise ConfigError(f"{path} exists already: resume it or choose another file") from None
        w = cls(path, fh)
        w.append(rec)
        return w

    @classmethod
    def resume(cls, path) -> "TraceWriter":
        path = str(path)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", TruncatedLineWarning)
            trace = read_trace(path)
        raw = Path(path).read_bytes()
        if not raw.endswith(b"\n"):  # cut the partial line the crash left
            with open(path, "r+b") as f:
                f.truncate(raw.rfind(b"\n") + 1)
                f.flush()
                os.fsync(f.fileno())
        return cls(path, open(path, "ab"), trace)

    def append(self, rec: dict) -> None:
        """Append one record; a failed write (a full disk, a lost folder) is one line,
        and the writer refuses further records (the line may be cut; a resume cuts it)."""
        if self._failed is not None:
            raise self._failed
        try:
            self._fh.write(_line(rec))
            self._fh.flush()
            os.fsync(self._fh.fileno())
        except OSError as e:
            self._failed = StationError(
                f"{self.path}: cannot append to the trace: {e.strerror or e}; it is intact up "
                "to its last complete line: free space (or fix the folder), then run the "
                "session again to resume")
            raise self._failed from None

    def event(self, kind: str, message: str, **extra) -> None:
        self.append({"record": "event", "t": utc_now(), "kind": kind, "message": message, **extra})

    def close(self) -> None:
        if not self._fh.closed:
            try:
                self._fh.close()
            except OSError:        # a write that failed already said so (append)
                pass

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def write_trace(path, header: dict, reference: dict | None, poses: list[dict],
                events: list[dict] = ()) -> None:
    """Write a whole trace at once (generator, tests), atomically (an existing
    file is replaced whole or not at all): same lines as the recorder's."""
    recs = [_header_record(header)]
    if reference is not None:
        recs.append({"record": "reference", **reference})
    recs += [{"record": "pose", **p} for p in poses]
    recs += [{"record": "event", **e} for e in events]
    write_atomic(path, b"".join(_line(r) for r in recs))
