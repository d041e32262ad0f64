"""Work off the GUI thread: session calls, device polling, fault questions.

* :class:`JobRunner` runs callables one after the other on its own thread
  (a ``QThreadPool`` of one) and reports each result or error back on the GUI
  thread through Qt signals, so device I/O and solving never block the GUI.
* :class:`LockedRig` wraps a :class:`drivers.rig.Rig` so that the session's
  worker and the live-readings poller never talk to one device at once (the
  drivers are not thread-safe: one Modbus client, one SYNC cycle at a time).
* :class:`FaultQuestion` carries a session's ``fault_policy`` question to the
  GUI thread and blocks the worker until the operator answered.
* :func:`poll_devices` is one round of live readings, device by device.
"""
from __future__ import annotations

import logging
import threading
import time
import traceback
from dataclasses import dataclass, field
from collections.abc import Callable
from typing import Any

from PySide6.QtCore import QObject, QRunnable, Qt, QThreadPool, Signal, Slot

log = logging.getLogger("station.gui")


class _JobSignals(QObject):
    finished = Signal(object, bool, object)     # job, ok, result or exception


class _Job(QRunnable):
    def __init__(self, fn: Callable[[], Any], signals: _JobSignals, on_done, on_error):
        super().__init__()
        self.setAutoDelete(False)        # the runner keeps it until it reported
        self.fn, self.signals = fn, signals
        self.on_done, self.on_error = on_done, on_error

    def run(self) -> None:
        try:
            result = self.fn()
        except BaseException as e:       # noqa: BLE001 - reported to the GUI, never lost
            e.gui_traceback = traceback.format_exc()
            self.signals.finished.emit(self, False, e)
        else:
            self.signals.finished.emit(self, True, result)


class JobRunner(QObject):
    """Runs jobs in submission order on one worker thread.

    ``submit(fn, on_done, on_error)``: ``fn()`` runs on the worker; ``on_done(result)``
    or ``on_error(exception)`` run on the GUI thread. ``busy`` is True while a job
    runs or waits; ``busyChanged`` tells.
    """

    busyChanged = Signal(bool)

    def __init__(self, name: str, parent: QObject | None = None):
        super().__init__(parent)
        self.name = name
        self.pool = QThreadPool(self)
        self.pool.setMaxThreadCount(1)
        self.pool.setExpiryTimeout(-1)
        self._jobs: list[_Job] = []
        self._signals = _JobSignals(self)     # GUI thread: the slot below runs there
        self._signals.finished.connect(self._finished, Qt.ConnectionType.QueuedConnection)

    @property
    def busy(self) -> bool:
        return bool(self._jobs)

    def submit(self, fn: Callable[[], Any], on_done: Callable[[Any], None] | None = None,
               on_error: Callable[[BaseException], None] | None = None) -> None:
        job = _Job(fn, self._signals, on_done, on_error)
        was_idle = not self._jobs
        self._jobs.append(job)
        if was_idle:
            self.busyChanged.emit(True)
        self.pool.start(job)

    @Slot(object, bool, object)
    def _finished(self, job: _Job, ok: bool, value) -> None:
        if job in self._jobs:
            self._jobs.remove(job)
        try:
            if ok:
                if job.on_done is not None:
                    job.on_done(value)
            elif job.on_error is not None:
                job.on_error(value)
            else:
                log.error("%s job failed: %s\n%s", self.name, value,
                          getattr(value, "gui_traceback", ""))
        finally:
            if not self._jobs:
                self.busyChanged.emit(False)

    def wait(self, msecs: int) -> bool:
        """Block until every job ran (at most ``msecs``); True if all finished."""
        return self.pool.waitForDone(msecs)


class LockedRig:
    """A :class:`drivers.rig.Rig` whose every method call holds one lock.

    The session's worker (move, snapshot, zero) and the poller (one read per
    device) both go through it. ``lock`` is re-entrant: a job may hold it across
    several calls (e.g. drive back to the reference, then zero).
    """

    def __init__(self, rig):
        self._rig = rig
        self.lock = threading.RLock()

    @property
    def wrapped(self):
        return self._rig

    def __getattr__(self, name: str):
        value = getattr(self._rig, name)
        if callable(value) and not isinstance(value, type):
            def call(*args, **kwargs):
                with self.lock:
                    return value(*args, **kwargs)
            call.__name__ = name
            return call
        return value


@dataclass
class DeviceReading:
    """One device in one polling round: ``ok``, its values or what is wrong; a motion
    capture's ``labels`` of its points (channels ``m1_x ..``)."""

    name: str
    ok: bool
    values: dict = field(default_factory=dict)
    text: str = ""
    labels: tuple = ()


def poll_devices(rig, timeout: float = 0.3,
                 simulated: bool = False) -> list[DeviceReading] | None:
    """One read of every device of ``rig`` (a :class:`LockedRig`); None if the
    devices were busy for ``timeout`` s (the worker is moving or measuring)."""
    from drivers.check import hint_for
    from drivers.errors import DeviceError

    if not rig.lock.acquire(timeout=timeout):
        return None
    try:
        out = []
        for d in rig.devices:
            if not d.is_open:
                out.append(DeviceReading(d.name, False, text="not connected: "
                                         + hint_for(d.name, simulated)))
                continue
            try:
                s = d.read()
            except (DeviceError, OSError) as e:
                out.append(DeviceReading(d.name, False, text=f"{e}; {hint_for(d.name, simulated)}"))
                continue
            out.append(DeviceReading(d.name, True, dict(s.values),
                                     labels=tuple(getattr(d, "labels", ()) or ())))
        return out
    finally:
        rig.lock.release()


class FaultQuestion(QObject):
    """The session's ``fault_policy``: asks the GUI, waits for the answer.

    Called on the execute worker: emits ``asked(request)`` (queued to the GUI
    thread) and blocks until :meth:`answer` is called with ``"retry"``,
    ``"skip"`` or ``"abort"`` (or :meth:`cancel_all` answers ``"abort"``).
    """

    asked = Signal(object)

    @dataclass
    class Request:
        pose: Any
        error: BaseException
        attempt: int
        event: threading.Event = field(default_factory=threading.Event)
        reply: str = "abort"

    def __init__(self, parent: QObject | None = None):
        super().__init__(parent)
        self._open: list[FaultQuestion.Request] = []
        self._lock = threading.Lock()
        self._closing = False

    def __call__(self, pose, error, attempt) -> str:
        req = FaultQuestion.Request(pose, error, attempt)
        with self._lock:
            if self._closing:
                return "abort"
            self._open.append(req)
        self.asked.emit(req)
        while not req.event.wait(0.1):
            if self._closing:
                req.reply = "abort"
                break
        with self._lock:
            if req in self._open:
                self._open.remove(req)
        return req.reply

    def answer(self, req: FaultQuestion.Request, reply: str) -> None:
        if reply not in ("retry", "skip", "abort", "reconnect"):
            raise ValueError(f"unknown answer {reply!r}")
        req.reply = reply
        req.event.set()

    def cancel_all(self) -> None:
        """Answer every open and future question with abort (the window closes)."""
        self._closing = True
        with self._lock:
            for req in self._open:
                req.reply = "abort"
                req.event.set()

    def reopen(self) -> None:
        self._closing = False


def limited_jog(session, axis: int, delta: float, speed: float,
                stop: threading.Event | None = None, dt: float = 0.1) -> float:
    """Move actuator ``axis`` by ``delta`` units at no more than ``speed`` units/s:
    steps of ``speed*dt``, each taking at least ``dt``. Returns the distance moved
    (less than ``delta`` if ``stop`` was set)."""
    if speed <= 0:
        raise ValueError("speed must be positive")
    step = speed * dt
    moved = 0.0
    sign = 1.0 if delta >= 0 else -1.0
    left = abs(delta)
    while left > 1e-12:
        if stop is not None and stop.is_set():
            break
        t0 = time.monotonic()
        d = min(step, left)
        session.jog(axis, sign * d)
        moved += sign * d
        left -= d
        rest = dt * d / step - (time.monotonic() - t0)
        if rest > 0:
            time.sleep(rest)
    return moved
