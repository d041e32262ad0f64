"""The one atomic file writer of the project: a reader (or a crash) never sees
half a file.

It lives below both :mod:`station` (parameter files, reports, generated traces)
and :mod:`drivers` (the simulator's endpoints and truth files), which both import
it from here.
"""
from __future__ import annotations

import os
import tempfile
from pathlib import Path


def process_umask() -> int:
    """The process umask without changing it (os.umask would race with other threads):
    from /proc on Linux, else the usual 022."""
    try:
        with open("/proc/self/status", encoding="ascii") as f:
            for line in f:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError, IndexError):
        pass
    return 0o022


def write_atomic(path, data: bytes) -> None:
    """Write ``data`` to ``path``: temporary file in the same folder, fsync,
    rename over ``path``, fsync the folder. On any failure the temporary file
    is removed and ``path`` is left as it was."""
    path = Path(path)
    folder = path.parent if str(path.parent) else Path(".")
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=folder)
    try:
        os.fchmod(fd, 0o666 & ~process_umask())   # as open() would; mkstemp makes 0600
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        try:
            os.unlink(tmp)
        except OSError:
            pass
        raise
    try:
        dfd = os.open(folder, os.O_RDONLY)
        try:
            os.fsync(dfd)
        finally:
            os.close(dfd)
    except OSError:
        pass


def check_writable(path, what: str = "the file", *, inputs=(), error=None) -> None:
    """Refuse, before any work, an output file that cannot be written: its folder
    missing or not writable (probed with an unnamed temporary file), the path a
    folder, or the same file as one of ``inputs``. Raises ``error`` (a
    :class:`calibration.errors.StationError` subclass; default ConfigError) with
    one line: ``cannot write <what> <path>: <reason>``."""
    from calibration.errors import ConfigError

    path = Path(path)
    folder = path.parent if str(path.parent) else Path(".")
    reason = None
    if not folder.is_dir():
        reason = f"the folder {folder} does not exist"
    elif path.is_dir():
        reason = "it is a folder"
    else:
        for other in inputs:
            if other and (os.path.abspath(other) == os.path.abspath(path)
                          or (path.exists() and os.path.exists(other)
                              and os.path.samefile(other, path))):
                reason = f"it is the input {other}; choose another file"
                break
    if reason is None:
        try:
            with tempfile.TemporaryFile(dir=folder):
                pass
        except OSError as e:
            reason = f"the folder {folder} is not writable ({e.strerror or e})"
    if reason:
        raise (error or ConfigError)(f"cannot write {what} {path}: {reason}")
