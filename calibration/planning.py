"""Pose planning: reachable poses sampled in a workspace box through IK.

Pure numerics: the caller passes the random generator. The count defaults to
the report's recommendation ``m >= 5 N_R / p`` (eq. 60).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calibration.errors import CalibrationError, UnreachablePose

# Workspace boxes of the report, relative to the base offset (x0, y0, z0)
# (brief section 1), phi +-20 deg; and for 7.5 relative to the chosen origin.
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
    ``accept(X, qm)`` approves (e.g. a safety envelope)."""
    if count < 1:
        raise CalibrationError("the pose count must be at least 1")
    max_draws = max_draws or 200 * count
    targets, qms = [], []
    draws = 0
    while len(targets) < count:
        if draws >= max_draws:
            raise CalibrationError(f"only {len(targets)} of {count} poses drawn in the "
                                   f"workspace box are reachable after {draws} draws")
        X = rng.uniform(bounds[:, 0], bounds[:, 1])
        draws += 1
        try:
            qm = robot.ik(X, xi, **(ik_options or {}))
        except UnreachablePose:
            continue
        if accept is not None and not accept(X, qm):
            continue
        targets.append(X)
        qms.append(qm)
    return Plan(np.array(targets), np.array(qms), draws)


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
        # the nearest pose not yet visited (the first of equals, in index order)
        d = np.max(np.abs(z - cur), axis=1)
        d[taken] = np.inf
        i = int(np.argmin(d))
        order[k] = i
        taken[i] = True
        cur = z[i]
    return order

