"""Where least squares is thrown off by a gross reading and does not converge: a robust
fit (soft L1) names the reading it rejects (:func:`robust_worst_row`), so that the gate
can leave its pose out and fit again (:func:`station.fitting.gate.rescue`).
"""
from __future__ import annotations

import math

import numpy as np

from calibration.errors import CalibrationError
from calibration.quality import OUTLIER_ALPHA, ROUNDOFF, Outlier, _group_rows


def robust_worst_row(model, x0, sigma_stated: dict | None = None, *, free=None,
                     alpha: float = OUTLIER_ALPHA) -> tuple[Outlier | None, np.ndarray | None]:
    """Where least squares is thrown off by a gross reading (it does not converge),
    the reading a robust fit rejects: ``scipy.optimize.least_squares`` with the
    soft-L1 loss from ``x0``, scaled per channel by the stated sigma or the
    residual's median absolute deviation (refitted once with it). Only the ``free``
    parameters move (a bool mask; default all): the fixed and the not identifiable
    ones keep their values, as in every fit of the station. A model whose rows come
    in groups read together (``row_group``: a point's x, y, z) is judged per group,
    on the norm of its residual. The row (a group's first) with the largest
    residual in robust sigmas, if beyond the Bonferroni threshold of the normal (a
    group: chi) distribution, else None; and the robust solution (None if the
    robust fit fails), a start for the refit without that reading."""
    from scipy.optimize import least_squares
    from scipy.special import chdtri, ndtri

    channels = tuple(model.channels)
    rc = np.asarray(model.row_channel)
    stated = sigma_stated or {}
    x_start = np.asarray(x0, dtype=float)
    mask = np.ones(len(x_start), bool) if free is None else np.asarray(free, bool)
    groups = getattr(model, "row_group", None)
    if groups is not None:
        rows, k = _group_rows(groups)
        gch = rc[rows[:, 0]]
        med_chi = math.sqrt(float(chdtri(k, 0.5)))
    else:
        rows, k, gch, med_chi = None, 1, rc, 1.0

    def unit(r):   # per reading: |r| (a group: its norm)
        return np.abs(r) if rows is None else np.linalg.norm(r[rows], axis=1)

    def scales(r):
        u = unit(r)
        s = np.ones(len(channels))
        for c, ch in enumerate(channels):
            uc = u[gch == c]
            mad = float(np.median(uc)) / (med_chi if rows is not None else 1 / 1.4826) \
                if uc.size else 1.0
            s[c] = float(stated[ch]) if stated.get(ch) else max(mad, ROUNDOFF)
        return s[gch]

    def full(v):
        x = x_start.copy()
        x[mask] = v
        return x

    def per_row(s):   # a group's scale on each of its rows
        if rows is None:
            return s
        out = np.empty(len(rc))
        out[rows] = s[:, None]
        return out

    # the fit itself on the rows: the norm of a group's residual is a poor linear model
    # where it is near the noise (its curvature is 1 / norm), and the steps on it
    # crawled (2323 evaluations on a marker trace whose fit on the rows takes 4); the
    # groups are judged below
    def fun(v, s):
        return model.evaluate(full(v))[0] / s

    def jac(v, s):
        return -model.evaluate(full(v))[1][:, mask] / s[:, None]

    if not mask.any():
        return None, None
    v = x_start[mask]
    try:
        r0 = model.evaluate(x_start)[0]
        s = scales(r0)
        for _ in range(2):
            sol = least_squares(fun, v, jac=jac, args=(per_row(s),), loss="soft_l1",
                                x_scale="jac", method="trf", tr_solver="exact",
                                max_nfev=200 * (len(v) + 1))
            v = sol.x
            r = model.evaluate(full(v))[0]
            if all(stated.get(ch) for ch in channels):
                break
            s = scales(r)
    except (ValueError, np.linalg.LinAlgError, FloatingPointError, CalibrationError):
        return None, None
    x = full(v)
    z = unit(r) / s
    z[unit(r) <= ROUNDOFF] = 0.0
    i = int(np.argmax(z))
    n = len(z)
    thr = (float(-ndtri(alpha / (2 * n))) if rows is None
           else math.sqrt(float(chdtri(k, alpha / n))))
    if not z[i] > thr:
        return None, x
    row = i if rows is None else int(rows[i, 0])
    res = float(r[row]) if rows is None else float(np.linalg.norm(r[rows[i]]))
    return Outlier(row, channels[rc[row]], res, float(z[i]), thr), x
