"""Choices that do not flip on round-off: near ties fall to the first candidate.

A plan is made of choices between candidates scored by floating-point arithmetic: the
pose of largest D-optimal gain, the nearest pose to visit next, the fit that explains
the readings best. Two candidates that score the same in exact arithmetic (the same
pose twice, poses symmetric about the box's centre, two fits that end in one minimum)
score a few units in the last place apart, and which one wins then depends on the
machine (its BLAS kernel, its SIMD paths). Here a candidate within :data:`RTOL` of the
best (relative to ``max(1, |best|)``) counts as tied with it, and of tied candidates the
first (in index order) is chosen: the same choice on every machine whatever the round-off.
"""
from __future__ import annotations

import numpy as np

#: scores this close (relative to ``max(1, |best|)``) are a tie
RTOL = 1e-9


def tied(a: float, b: float, rtol: float = RTOL) -> bool:
    """Are ``a`` and ``b`` equal but for round-off (both finite)?"""
    return abs(a - b) <= rtol * max(1.0, abs(a), abs(b))


def first_max(values, rtol: float = RTOL) -> int:
    """The index of the largest value, the first of those tied with it (``-inf`` and nan
    are never chosen while a finite value is left)."""
    v = np.asarray(values, dtype=float)
    finite = np.isfinite(v)
    if not finite.any():
        return int(np.argmax(np.where(np.isnan(v), -np.inf, v)))
    best = float(np.max(v[finite]))
    return int(np.flatnonzero(finite & (v >= best - rtol * max(1.0, abs(best))))[0])


def first_min(values, rtol: float = RTOL) -> int:
    """The index of the smallest value, the first of those tied with it (``inf`` and nan
    are never chosen while a finite value is left)."""
    v = np.asarray(values, dtype=float)
    return first_max(-v, rtol)


def less(a: tuple, b: tuple, rtol: float = RTOL) -> bool:
    """``a < b`` compared item by item, the numbers tied but for round-off (:func:`tied`)
    counting as equal: of two keys tied in every item, neither is less."""
    for x, y in zip(a, b):
        if x == y or (isinstance(x, float) and isinstance(y, float) and tied(x, y, rtol)):
            continue
        return x < y
    return len(a) < len(b)
