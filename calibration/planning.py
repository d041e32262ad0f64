"""Pose planning: reachable poses sampled in a workspace box through IK.

Pure numerics: the caller passes the random generator. The count defaults to
the report's recommendation ``m >= 5 N_R / p`` (eq. 60).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calibration.errors import CalibrationError, UnreachablePose
from calibration.ties import first_min

# Workspace boxes of the report, relative to the base offset (x0, y0, z0)
# (docs/models.md, "Serial part (SM)"), phi +-20 deg; and for 7.5 relative to the chosen origin.
DEG20 = np.radians(20.0)
SM_BOX_7_1 = {"x": (1.0, 1.5), "y": (0.5, 1.0), "z": (-0.75, 0.75), "phi": (-DEG20, DEG20)}
SM_BOX_7_5 = {"x": (-0.25, 0.25), "y": (-0.25, 0.25), "z": (-0.75, 0.75), "phi": (-DEG20, DEG20)}
PM_BOX = {"alpha": (-DEG20, DEG20), "beta": (-DEG20, DEG20), "gamma": (-DEG20, DEG20)}


@dataclass(frozen=True)
class Plan:
    """Planned poses: ``targets (m, len(coords))`` and their actuator values ``qm (m, n)``."""

    targets: np.ndarray
    qm: np.ndarray
    draws: int


def box_array(robot, box: dict, offset=None) -> np.ndarray:
    """Box as ``(len(coords), 2)`` bounds; ``offset`` is added to the coordinates."""
    try:
        b = np.array([box[c] for c in robot.coords], dtype=float)
    except KeyError as e:
        raise CalibrationError(f"workspace box lacks coordinate {e.args[0]!r} "
                               f"(needs {', '.join(robot.coords)})") from None
    if offset is not None:
        b = b + np.asarray(offset, dtype=float)[:, None]
    if np.any(b[:, 0] > b[:, 1]):
        raise CalibrationError("workspace box has a lower bound above its upper bound")
    return b


def sample_poses(robot, xi, bounds: np.ndarray, count: int, rng: np.random.Generator,
                 *, max_draws: int | None = None, ik_options: dict | None = None,
                 accept=None) -> Plan:
    """Draw poses uniformly in ``bounds`` and keep those the IK of the model
    ``xi`` reaches (a planner never sends an unreachable pose) and, if given,
    ``accept(X, qm)`` approves (e.g. a safety envelope).

    A robot with ``ik_many`` (the IK of many poses at once) is asked for a batch of
    draws at a time; the generator is then left exactly where drawing one pose at a
    time would leave it: the same poses either way (actuator values to rounding: the
    batch's IK uses numpy's trigonometry, ``ik`` Python's)."""
    if count < 1:
        raise CalibrationError("the pose count must be at least 1")
    max_draws = max_draws or 200 * count
    if hasattr(robot, "ik_many"):
        targets, qms, draws = _sample_batched(robot, xi, bounds, count, rng, max_draws,
                                              ik_options or {}, accept)
    else:
        targets, qms, draws = _sample_one_by_one(robot, xi, bounds, count, rng, max_draws,
                                                 ik_options or {}, accept)
    if len(targets) < count:
        raise CalibrationError(f"only {len(targets)} of {count} poses drawn in the "
                               f"workspace box are reachable after {draws} draws")
    return Plan(np.array(targets), np.array(qms), draws)


def _sample_one_by_one(robot, xi, bounds, count, rng, max_draws, ik_options, accept):
    targets, qms = [], []
    draws = 0
    while len(targets) < count and draws < max_draws:
        X = rng.uniform(bounds[:, 0], bounds[:, 1])
        draws += 1
        try:
            qm = robot.ik(X, xi, **ik_options)
        except UnreachablePose:
            continue
        if accept is not None and not accept(X, qm):
            continue
        targets.append(X)
        qms.append(qm)
    return targets, qms, draws


def _sample_batched(robot, xi, bounds, count, rng, max_draws, ik_options, accept):
    """:func:`_sample_one_by_one` with the IK of a batch of draws at once: the same poses
    (a batch's rows are the draws one at a time would make, in order), and the
    generator advanced by exactly the draws used."""
    targets, qms = [], []
    draws = 0
    while len(targets) < count and draws < max_draws:
        state = rng.bit_generator.state
        batch = min(max_draws - draws, max(16, 4 * (count - len(targets))))
        X = rng.uniform(bounds[:, 0], bounds[:, 1], size=(batch, len(bounds)))
        qm, ok = robot.ik_many(X, xi, **ik_options)
        used = batch
        for i in np.flatnonzero(ok):
            if accept is not None and not accept(X[i], qm[i]):
                continue
            targets.append(X[i])
            qms.append(qm[i])
            if len(targets) == count:
                used = int(i) + 1
                break
        if used < batch:                   # rewind, then draw only what was used
            rng.bit_generator.state = state
            rng.uniform(bounds[:, 0], bounds[:, 1], size=(used, len(bounds)))
        draws += used
    return targets, qms, draws


def scale_box(bounds: np.ndarray, scale: float, centre=None) -> np.ndarray:
    """``bounds (k, 2)`` shrunk by ``scale`` about ``centre`` (default: its middle)."""
    c = bounds.mean(axis=1) if centre is None else np.asarray(centre, dtype=float)
    return c[:, None] + scale * (bounds - c[:, None])


def order_for_travel(qm: np.ndarray, start=None, scale=None) -> np.ndarray:
    """A visiting order that keeps actuator travel short (greedy nearest
    neighbour in scaled actuator space). Returns indices."""
    qm = np.asarray(qm, dtype=float)
    s = np.ptp(qm, axis=0) if scale is None else np.asarray(scale, dtype=float)
    s = np.where(s > 0, s, 1.0)
    z = qm / s
    n = len(z)
    cur = z[0] if start is None else np.asarray(start, dtype=float) / s
    taken = np.zeros(n, dtype=bool)
    order = np.empty(n, dtype=np.intp)
    for k in range(n):
        # the nearest pose not yet visited (the first of equals but for round-off, in
        # index order: calibration/ties.py)
        d = np.max(np.abs(z - cur), axis=1)
        d[taken] = np.inf
        i = first_min(d)
        order[k] = i
        taken[i] = True
        cur = z[i]
    return order

