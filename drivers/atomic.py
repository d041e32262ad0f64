"""The one atomic file writer of the project: a reader (or a crash) never sees
half a file.

It lives below both :mod:`station` (parameter files, reports, generated traces)
and :mod:`drivers` (the simulator's endpoints and truth files), which both import
it from here.
"""
from __future__ import annotations

import errno
import os
import stat
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
    is removed and ``path`` is left as it was; an OSError names ``path`` (never
    the temporary file). An existing ``path`` that is not a regular file (a
    device such as ``/dev/null``, a FIFO, a folder) is refused, never replaced."""
    path = Path(path)
    folder = path.parent if str(path.parent) else Path(".")
    _refuse_special(path)
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=folder)
    except OSError as e:
        raise OSError(e.errno, e.strerror, str(path)) from None
    try:
        os.fchmod(fd, 0o666 & ~process_umask())   # as open() would; mkstemp makes 0600
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        _refuse_special(path)                     # made one while we wrote?
        os.replace(tmp, path)
    except BaseException as e:
        try:
            os.unlink(tmp)
        except OSError:
            pass
        if isinstance(e, OSError) and not isinstance(e, NotRegularFile):
            raise OSError(e.errno, e.strerror or str(e), str(path)) from None
        raise
    try:
        dfd = os.open(folder, os.O_RDONLY)
        try:
            os.fsync(dfd)
        finally:
            os.close(dfd)
    except OSError:
        pass


class NotRegularFile(OSError):
    """An output path that exists and is not a regular file (a device, a FIFO, a
    socket, a folder): written over, it would be replaced by a file."""


def _refuse_special(path: Path) -> None:
    try:
        st = os.stat(path)
    except OSError:
        return
    if not stat.S_ISREG(st.st_mode):
        raise NotRegularFile(errno.EEXIST, f"exists and is {_kind(st.st_mode)}, not a "
                             "regular file: choose a file name", str(path))


def _kind(mode: int) -> str:
    if stat.S_ISDIR(mode):
        return "a folder"
    if stat.S_ISCHR(mode) or stat.S_ISBLK(mode):
        return "a device"
    if stat.S_ISFIFO(mode):
        return "a pipe (FIFO)"
    if stat.S_ISSOCK(mode):
        return "a socket"
    return "a special file"


def check_writable(path, what: str = "the file", *, inputs=(), error=None) -> None:
    """Refuse, before any work, an output file that cannot be written: an empty
    name, its folder missing or not writable (probed with an unnamed temporary
    file), the path a folder, a device, a FIFO or another file that is not a
    regular one, or the same file as one of ``inputs`` (by name, through a link,
    or a hard link of it). Raises ``error`` (a
    :class:`calibration.errors.StationError` subclass; default ConfigError) with
    one line: ``cannot write <what> <path>: <reason>``."""
    from calibration.errors import ConfigError

    if path is None or str(path).strip() == "":
        raise (error or ConfigError)(f"cannot write {what}: the file name is empty")
    path = Path(path)
    folder = path.parent if str(path.parent) else Path(".")
    reason = None
    if not folder.is_dir():
        reason = f"the folder {folder} does not exist"
    else:
        reason = _same_as_input(path, inputs)
        if reason is None:
            try:
                st = os.stat(path)
            except OSError:
                st = None
            if st is not None and stat.S_ISDIR(st.st_mode):
                reason = "it is a folder"
            elif st is not None and not stat.S_ISREG(st.st_mode):
                reason = (f"it exists and is {_kind(st.st_mode)}, not a regular file (it "
                          "would be replaced by the file); choose a file name")
    if reason is None:
        try:
            with tempfile.TemporaryFile(dir=folder):
                pass
        except OSError as e:
            reason = f"the folder {folder} is not writable ({e.strerror or e})"
    if reason:
        raise (error or ConfigError)(f"cannot write {what} {path}: {reason}")


def _same_as_input(path: Path, inputs) -> str | None:
    for other in inputs:
        if not other:
            continue
        if os.path.abspath(other) == os.path.abspath(path) or (
                os.path.realpath(other) == os.path.realpath(path)):
            return f"it is the input {other}; choose another file"
        try:
            if os.path.samefile(other, path):
                return f"it is the input {other}; choose another file"
        except OSError:
            pass
    return None


def check_outputs(*outputs, inputs=(), error=None) -> None:
    """Every output of one command checked before it writes any
    (:func:`check_writable` each; ``outputs`` are ``(path, what)``, path None = not
    asked for, ``""`` refused): none may be an input, a special file, or the same
    file as another output."""
    from calibration.errors import ConfigError

    seen: dict = {}
    for path, what in outputs:
        if path is None:
            continue
        check_writable(path, what, inputs=inputs, error=error)
        key = os.path.realpath(path)
        if key in seen:
            raise (error or ConfigError)(f"cannot write {what} {path}: it is also {seen[key]}")
        seen[key] = what


def check_output_folder(folder, what: str, files=(), *, inputs=(), error=None) -> None:
    """An output folder (``run --out``, ``study --out``) and the ``files`` a command
    writes in it: the folder, if it exists, a folder; its parent there; none of the
    files an input or a special file."""
    from calibration.errors import ConfigError

    err = error or ConfigError
    if folder is None or str(folder).strip() == "":
        raise err(f"cannot write {what}: the folder name is empty")
    folder = Path(folder)
    same = _same_as_input(folder, inputs)
    if same is not None:
        raise err(f"cannot write {what} {folder}: {same}")
    if folder.exists() and not folder.is_dir():
        raise err(f"cannot write {what} {folder}: it exists and is not a folder")
    parent = folder.parent if str(folder.parent) else Path(".")
    if not folder.exists() and not parent.is_dir():
        raise err(f"cannot write {what} {folder}: the folder {parent} does not exist")
    if folder.is_dir():
        check_outputs(*((str(folder / name), f"{what}'s {name}") for name in files),
                      inputs=inputs, error=error)
