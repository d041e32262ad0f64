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
limits is refused, nothing moves). Device faults are not retried here: the test stops
with the device's error, in one line (what was measured is not written).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import numpy as np

from calibration import iso9283
from calibration.errors import StationError
from station.planning.envelope import limit_violation


@dataclass
class Readings:
    """One program's cycles: ``points (cycles, 5, M, 3)`` m in the instrument's frame (NaN:
    not seen), ``qm (cycles, 5, n)`` the actuator values read, ``t`` the snapshots' start
    times (ISO 8601), in P1..P5 order within each cycle."""

    points: np.ndarray
    qm: np.ndarray
    t: list


Progress = Callable[[str], None]


def _reading(snap, n_points: int, n_act: int) -> tuple[np.ndarray, np.ndarray]:
    m = snap.mean
    pts = np.array([[m.get(f"m{j}_{c}", math.nan) for c in "xyz"]
                    for j in range(1, n_points + 1)], dtype=float)
    return pts, np.array([m[f"qm{i + 1}"] for i in range(n_act)], dtype=float)


def run_program(rig, config, program, cycles: int, n_points: int, *, name: str = "",
                progress: Progress | None = None) -> Readings:
    """``cycles`` cycles of ``program (5, n)`` at the robot of ``rig`` (module doc)."""
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
    rig.move_to(q[order[-1]])
    for c in range(cycles):
        for k in order:
            rig.move_to(q[k])
            snap = rig.snapshot()
            points[c, k], qm[c, k] = _reading(snap, n_points, n_act)
            times[c][k] = snap.t_start
        if progress:
            seen = np.all(np.isfinite(points[c]), axis=(1, 2))
            note = "" if seen.all() else (" (not every point seen at "
                                          + ", ".join(iso9283.POINTS[k] for k in
                                                      np.flatnonzero(~seen)) + ")")
            progress(f"{name}: cycle {c + 1} of {cycles} measured{note}")
    return Readings(points, qm, times)
