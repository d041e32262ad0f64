"""One session per output folder: an OS lock held for the whole session.

Two sessions appending to one trace interleave half-lines and duplicate pose
indices, after which the trace can be neither calibrated nor resumed. A
:class:`FolderLock` holds ``fcntl.flock`` (exclusive, non-blocking) on
``<folder>/session.lock`` from the moment a session opens the folder until it is
closed; the file records who holds it (pid, host, start, command) so that the
second session is refused with one line naming the first.

The kernel drops a flock when its process dies, however it dies (SIGKILL, a
power cut of the PC ends everything anyway), so a lock left by a crashed run is
never held: the next session takes it over at once and says whose it was. The
file itself is never removed (removing it would let a waiting process lock an
unlinked inode while a third one locks a new file); it is emptied on release.
"""
from __future__ import annotations

import datetime as _dt
import errno
import fcntl
import json
import os
import socket
import sys
from pathlib import Path

from calibration.errors import StationError

LOCK = "session.lock"


class FolderLocked(StationError):
    """Another session holds the folder (the message names its process)."""


def _holder_text(info: dict) -> str:
    if not info:
        return "another process"
    who = f"pid {info.get('pid', '?')} on {info.get('host', '?')}"
    if info.get("start"):
        who += f", started {info['start']}"
    if info.get("command"):
        who += f" ({info['command']})"
    return who


def _alive(pid) -> bool:
    try:
        os.kill(int(pid), 0)
    except (ProcessLookupError, ValueError, TypeError):
        return False
    except PermissionError:
        return True
    return True


class FolderLock:
    """The lock of one output folder (created if missing). ``acquire`` raises
    :class:`FolderLocked` naming the holder; ``stale`` is what a crashed holder left
    (its record) when this one took the lock over, else None."""

    def __init__(self, folder):
        self.folder = Path(folder)
        self.path = self.folder / LOCK
        self._fd: int | None = None
        self.stale: dict | None = None

    @property
    def held(self) -> bool:
        return self._fd is not None

    def acquire(self) -> "FolderLock":
        if self._fd is not None:
            return self
        try:
            self.folder.mkdir(parents=True, exist_ok=True)
            fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
        except OSError as e:
            raise StationError(f"{self.path}: cannot open the session lock: "
                               f"{e.strerror or e}") from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as e:
            info = _read(fd)
            os.close(fd)
            if e.errno in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES):
                raise FolderLocked(f"{self.folder}: another session is using this folder "
                                   f"({_holder_text(info)}): wait for it to finish or choose "
                                   "another folder") from None
            raise StationError(f"{self.path}: cannot lock: {e.strerror or e}") from None
        left = _read(fd)
        self.stale = left or None           # a holder that died without releasing
        record = {"pid": os.getpid(), "host": socket.gethostname(),
                  "start": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
                  "command": " ".join(os.path.basename(a) if i == 0 else a
                                      for i, a in enumerate(sys.argv[:6]))}
        try:
            _write(fd, json.dumps(record) + "\n")
        except OSError as e:
            os.close(fd)
            raise StationError(f"{self.path}: cannot write the session lock: "
                               f"{e.strerror or e}") from None
        self._fd = fd
        return self

    def stale_text(self) -> str | None:
        """One line on a taken-over lock (None if there was none)."""
        if not self.stale:
            return None
        state = ("no longer running" if not _alive(self.stale.get("pid"))
                 or self.stale.get("host") != socket.gethostname() else "not holding it")
        return (f"took over the folder's lock left by {_holder_text(self.stale)}, {state} "
                "(a crashed run)")

    def release(self) -> None:
        fd, self._fd = self._fd, None
        if fd is None:
            return
        try:
            _write(fd, "")
        except OSError:
            pass                            # a full disk: the lock still goes with the fd
        finally:
            os.close(fd)                    # drops the flock

    def __enter__(self):
        return self.acquire()

    def __exit__(self, *exc):
        self.release()


def holder(folder) -> dict | None:
    """The record of the session holding ``folder``'s lock, or None if none holds it."""
    path = Path(folder) / LOCK
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:
        return None
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
        except OSError:
            return _read(fd) or {}
        fcntl.flock(fd, fcntl.LOCK_UN)
        return None
    finally:
        os.close(fd)


def _read(fd: int) -> dict:
    try:
        os.lseek(fd, 0, os.SEEK_SET)
        raw = os.read(fd, 4096)
        info = json.loads(raw) if raw.strip() else {}
        return info if isinstance(info, dict) else {}
    except (OSError, ValueError):
        return {}


def _write(fd: int, text: str) -> None:
    os.ftruncate(fd, 0)
    os.lseek(fd, 0, os.SEEK_SET)
    os.write(fd, text.encode())
    os.fsync(fd)
