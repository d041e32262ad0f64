"""The ISO 9283 test at the robot: n cycles of a program's five measuring poses, each
measured by the station's point instrument (docs/accuracy.md).

A program is the five poses' actuator values ``(5, n)`` in the order P1..P5
(:data:`calibration.iso9283.POINTS`). Before its first cycle the robot goes to P2, the
cycle's last pose, so that every cycle, the first one too, approaches each pose from the
one before it (P2 to P1, P1 to P5, P5 to P4, ...): the standard's unidirectional
approach, the same backlash every time. Each pose is a snapshot of the rig
(:meth:`drivers.rig.Rig.snapshot`: the drives' positions, the motion capture's mean of
its frames); its reading is the points on the tool in the instrument's frame (m, NaN
where a point was not seen) and the actuator values read.

Every move is checked against the station config's envelope before it starts
(:func:`station.planning.envelope.limit_violation`: a pose beyond the config's actuator
limits is refused, nothing moves). A device fault goes to the ``fault_policy`` where one
is given (the wizard asks the operator), else the test stops with the device's error in
one line (``app.py accuracy``). *Retry*: a pause, the rig recovered (a drive's fault
reset, or the devices connected anew) and the pose approached again from the one before
it (the same direction); *skip*: the rest of that cycle is left out (its poses are not
in the figures) and the next cycle starts from P2 as every cycle does; *abort*: the test
stops (:class:`TestStopped`). ``stop()`` is asked before every move: the operator's Stop
ends the test there. A test that stops writes nothing: what was measured is dropped.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Callable

import numpy as np

from calibration import iso9283
from calibration.errors import StationError
from drivers.errors import DeviceError
from station.planning.envelope import limit_violation
from station.session.device_loss import backoff


@dataclass
class Readings:
    """One program's cycles: ``points (cycles, 5, M, 3)`` m in the instrument's frame (NaN:
    not seen), ``qm (cycles, 5, n)`` the actuator values read, ``t`` the snapshots' start
    times (ISO 8601), in P1..P5 order within each cycle."""

    points: np.ndarray
    qm: np.ndarray
    t: list


Progress = Callable[[str], None]


class TestStopped(StationError):
    """The test stopped before its last cycle (the operator's Stop, or Abort after a
    fault); nothing was written."""

    __test__ = False          # not a pytest class


@dataclass(frozen=True)
class Where:
    """Where the test is: the program, its cycle (1-based) of ``cycles``, the pose."""

    program: str
    cycle: int
    cycles: int
    pose: str

    def __str__(self) -> str:
        return f"{self.pose} of cycle {self.cycle} of {self.cycles}, the {self.program} program"


def _reading(snap, n_points: int, n_act: int) -> tuple[np.ndarray, np.ndarray]:
    m = snap.mean
    pts = np.array([[m.get(f"m{j}_{c}", math.nan) for c in "xyz"]
                    for j in range(1, n_points + 1)], dtype=float)
    return pts, np.array([m[f"qm{i + 1}"] for i in range(n_act)], dtype=float)


def run_program(rig, config, program, cycles: int, n_points: int, *, name: str = "",
                progress: Progress | None = None, on_pose=None, stop=None,
                fault_policy=None) -> Readings:
    """``cycles`` cycles of ``program (5, n)`` at the robot of ``rig`` (module doc).
    ``on_pose(where)`` is told each pose (:class:`Where`) before the robot moves there;
    ``fault_policy(where, error, attempt)`` answers ``"retry"``, ``"skip"`` or ``"abort"``."""
    q = np.asarray(program, dtype=float)
    n_act = q.shape[1]
    for k, p in enumerate(q):
        why = limit_violation(tuple(map(float, p)), config.envelope)
        if why is not None:
            raise StationError(f"the {name} program's {iso9283.POINTS[k]} is beyond the station "
                               f"config's limits: {why}")
    order = [iso9283.POINTS.index(p) for p in iso9283.CYCLE]
    points = np.full((cycles, 5, n_points, 3), np.nan)
    qm = np.full((cycles, 5, n_act), np.nan)
    times = [[""] * 5 for _ in range(cycles)]
    if progress:
        progress(f"{name}: to {iso9283.CYCLE[-1]}, where every cycle starts from")
    _stopped(stop, Where(name, 1, cycles, iso9283.CYCLE[0]))
    rig.move_to(q[order[-1]])
    again = False                # approach the next pose from the one before it first
    for c in range(cycles):
        left = None
        for i, k in enumerate(order):
            where = Where(name, c + 1, cycles, iso9283.POINTS[k])
            if on_pose:
                on_pose(where)
            snap = _pose(rig, q, order[i - 1], k, where, again, stop, fault_policy)
            again = snap is None
            if snap is None:             # skipped: the rest of the cycle left out
                left = where.pose
                break
            points[c, k], qm[c, k] = _reading(snap, n_points, n_act)
            times[c][k] = snap.t_start
        if progress:
            seen = np.all(np.isfinite(points[c]), axis=(1, 2))
            note = (f" (left out from {left} on, after a fault)" if left else "" if seen.all()
                    else " (not every point seen at " + ", ".join(
                        iso9283.POINTS[k] for k in np.flatnonzero(~seen)) + ")")
            progress(f"{name}: cycle {c + 1} of {cycles} measured{note}")
    return Readings(points, qm, times)


def _stopped(stop, where: Where) -> None:
    if stop is not None and stop():
        raise TestStopped(f"stopped before {where}; nothing written")


def _pose(rig, q, before: int, k: int, where: Where, again: bool, stop, fault_policy):
    """Move to pose ``k`` and take its snapshot (approached from ``before`` first where
    ``again``); None where the operator skips the rest of the cycle after a fault."""
    attempt = 0
    while True:
        _stopped(stop, where)
        try:
            if again:
                rig.move_to(q[before])
            rig.move_to(q[k])
            return rig.snapshot()
        except DeviceError as e:
            if fault_policy is None:
                raise
            action = fault_policy(where, e, attempt)
            if action == "skip":
                return None
            if action != "retry":
                raise TestStopped(f"stopped at {where} after a fault ({e}); nothing "
                                  "written") from e
            attempt += 1
            again = True
            time.sleep(backoff(attempt))
            try:
                rig.recover()
            except DeviceError:
                pass             # the next attempt says what is wrong
