"""The gate's check of the points on the tool (sm-markers with two points or more): does
each point move with the tool?

A point fixed on another link than the tip (a reflector on the forearm), or another
point's columns, moves otherwise than the tool does. Least squares spreads its misfit
over every point (a point on link 5 of a 6-axis arm: 53 mm RMS, the two on the tool 28
and 30 mm, and "fit quality: passed" without a stated noise), so each point is judged
against a fit made *without* it: the robot, the instrument's frame and the other points
from that fit, the point's own best place on the tool (the mean of its readings in the
tip's frame: exact, the tip's rotation is orthogonal), and its residual RMS against the
other points' in that fit. A point :data:`POINT_RATIO` times above every other one is
named and the fit refused, whatever the noise.
"""
from __future__ import annotations

import dataclasses

import numpy as np

from calibration.errors import CalibrationError

#: a point whose RMS about its best place on the tool is more than this many times every
#: other point's (in the fit made without it) does not move with the tool
POINT_RATIO = 5.0
#: ... and more than this (m) above them: noise-free data are not judged by a ratio
POINT_FLOOR = 1e-5


def _without(trace, j: int):
    """``trace`` with point ``j`` (0-based) unseen; a fit pose that saw only it is left
    out of the fit (``use = "excluded"``)."""
    poses = []
    for p in trace.poses:
        if p.get("use", "fit") != "fit" or p["index"] in trace.remeasured:
            poses.append(p)
            continue
        marks = [None if k == j else c for k, c in enumerate(p["markers"])]
        poses.append(dict(p, markers=marks) if any(c is not None for c in marks)
                     else dict(p, use="excluded"))
    return dataclasses.replace(trace, poses=poses)


def _spread(R, p, P) -> float:
    """3D RMS of readings ``P (s, 3)`` about their best place on the tool (tip rotations
    ``R (s, 3, 3)``, origins ``p (s, 3)``)."""
    local = np.einsum("sji,sj->si", R, P - p)          # R^T (P - p)
    return float(np.sqrt(np.mean(np.sum((local - local.mean(axis=0)) ** 2, axis=1))))


def check_points(quality, trace, model, result, *, refit, hold=()) -> None:
    """The module's check; a failed one is the gate's ``points`` check (one line naming
    the point, its RMS and the others')."""
    if getattr(model, "method", None) != "sm-markers" or model.n_markers < 2:
        return
    seen = model.seen
    for j in range(model.n_markers):
        if seen[:, j].sum() < 3 or not seen[:, np.arange(model.n_markers) != j].any():
            continue
        try:
            m2, r2 = refit(_without(trace, j), result.x, hold=hold)
        except CalibrationError:
            continue
        _, T, _, _ = model.predict(r2.x)                  # the tip frames of every fit pose
        rows = seen[:, j]
        own = _spread(T[rows, :3, :3], T[rows, :3, 3], model.points[rows, j])
        errs = m2.point_errors(r2.residual)
        others = max(float(np.sqrt(np.mean(errs[m2.marker_of == k] ** 2)))
                     for k in np.unique(m2.marker_of))
        if own > POINT_RATIO * others and own - others > POINT_FLOOR:
            quality.check("points", False, f"points: point {j + 1} does not move with the tool: "
                          f"{own * 1e3:.4g} mm RMS about its best place on it, "
                          f"{own / max(others, 1e-300):.3g} times the other points' "
                          f"({others * 1e3:.4g} mm) in the fit without it (fixed on another "
                          "link? another point's columns?); leave it out (--ignore-columns) "
                          "or check where it is fixed", point=j + 1, rms=own, others=others)
            return
