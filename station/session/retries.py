"""The session's retry policy: what it does when a device faults.

A pose's fault goes to the session's ``fault_policy`` (``"retry"``, ``"skip"`` or
``"abort"``; :func:`retry_then_skip` is the headless one, the wizard asks the operator).
A step that cannot be skipped (the reference step, the wrist's start step, the return to
the reference) is retried by :meth:`Retries._reference_retried` up to the policy's
``retries`` and ``window``. Either way a retry is a ``fault`` event naming the device, a
pause (:func:`station.session.device_loss.backoff`: a short outage passes) and the rig
recovered; after the last one :func:`station.session.device_loss.probe` tells a device
gone (:class:`~station.session.device_loss.DeviceLost`, the session stops) from a pose
or step that kept failing.
"""
from __future__ import annotations

import time
from typing import Callable

from drivers.errors import DeviceError
from station.outputs.units import describe_error
from station.recording.planned_pose import PlannedPose
from station.session import device_loss

# -> "retry" | "skip" | "abort" | "reconnect" (abort to connect the lost devices anew)
FaultPolicy = Callable[[PlannedPose, DeviceError, int], str]


def retry_then_skip(retries: int = 3, window: float = 0.0) -> FaultPolicy:
    """The headless policy: retry a faulty pose ``retries`` times (after pauses of
    0.25, 0.5, 1 s: :func:`station.session.device_loss.backoff`), and for as long as
    ``window`` seconds from its first fault (the station config's
    ``session.retry_window``), then skip it, unless the device itself is gone
    (:func:`station.session.device_loss.probe`: the session stops)."""
    first: dict = {}

    def policy(pose, error, attempt):
        now = time.monotonic()
        if attempt == 0:
            first[pose.index] = now
        within = now - first.setdefault(pose.index, now) < window
        return "retry" if attempt < retries or within else "skip"
    policy.retries = retries      # the reference step's retries (Session.reference_retries)
    policy.window = window        # ... and its window (Session.retry_window)
    return policy


#: retries of the reference step where the fault policy states none (an operator's,
#: asked per pose in the wizard): as many as :func:`retry_then_skip`'s default
REFERENCE_RETRIES = 3


class Retries:
    """The retries of a :class:`~station.session.session.Session` (a part of it: reads
    ``reference_retries``, ``retry_window``, ``simulated``, ``rig``; writes events)."""

    def _reference_retried(self, what: str, step):
        """``step(attempt)`` (0-based), retried after a DeviceError the way a pose is
        (:meth:`_measure`): a ``fault`` event naming the device, a pause
        (:func:`station.session.device_loss.backoff`), the rig recovered, and ``step`` again
        from its start (it returns the arm where it began and takes every reading
        anew), at most :attr:`reference_retries` times. Then
        :func:`station.session.device_loss.probe` tells a device gone (:class:`DeviceLost`,
        naming it and what to check) from a step that kept failing (its last error).
        The step cannot be skipped: nothing is measured without it. Faults are
        recorded in the trace (its header written first where there is none yet: a
        trace without a reference record resumes with the reference step)."""
        rig = self._rig()
        attempt = 0
        first = None
        while True:
            try:
                closed = device_loss.not_connected(rig)     # a reconnection that failed
                if closed is not None:
                    raise closed
                return step(attempt)
            except DeviceError as e:
                first = time.monotonic() if first is None else first
                self._ensure_trace()
                self._event("fault", f"{what}, attempt {attempt + 1}: "
                            f"{describe_error(e, self.units)}", device=e.device, step=what)
                if (attempt >= self.reference_retries
                        and time.monotonic() - first >= self.retry_window):
                    self._raise_if_lost(rig, e)              # the device, or this step?
                    raise
                attempt += 1
                self._pause_to_retry(what, attempt, step=what)

    def _raise_if_lost(self, rig, error: DeviceError) -> None:
        """After retries: raise :class:`DeviceLost` (with a ``lost`` event) where the
        device itself is gone (:func:`station.session.device_loss.probe`), else return."""
        lost = device_loss.probe(rig, error, self.simulated)
        if lost is not None:
            self._event("lost", str(lost), device=lost.device)
            raise lost from error

    def _pause_to_retry(self, what: str, attempt: int, **extra) -> None:
        """Before retry ``attempt`` (1-based) of ``what``: a ``retry`` event, the backoff
        pause (:func:`station.session.device_loss.backoff`: a short outage passes) and the rig
        recovered."""
        pause = device_loss.backoff(attempt)
        self._event("retry", f"{what}: retry {attempt} in {pause:g} s", **extra)
        time.sleep(pause)
        self._recover()

    def _recover(self) -> None:
        """Before a retry or after a skip: reset a faulted drive, or reconnect a device
        that dropped (:meth:`drivers.rig.Rig.recover`)."""
        try:
            self.rig.recover()
        except DeviceError as e:
            self._event("fault", f"recovery failed: {e}", device=e.device)
