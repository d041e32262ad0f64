"""The record of one iteration of Algorithm 2 (:class:`Iteration`: the data behind
the report's figures).

What it saves: the variance and the condition number of an iteration are kept
as the triangle they come from and formed only when first read (the loop itself
needs neither; a caller reading the history pays for what it reads): per
iteration an SVD of ``R`` and the row norms of ``R^-1``.
"""
from __future__ import annotations

import numpy as np

from calibration.solver.factored import formed_condition, row_norms2


class Iteration:
    """One iteration's record (the data behind the report's figures); read-only.

    x:                 ``(N,)`` parameters after the step
    variance:          ``(N,)`` variance of each parameter (NaN where not calibrated;
                       formed when first read, like the condition number)
    condition_number:  of the scaled, weighted observation matrix (computed from
                       the iteration's triangle when first read: the loop itself
                       does not need it)
    step:              max ``|d xi_R|``
    cost:              ``0.5 r^T L r`` before the step
    sigma:             channel -> sigma estimate
    """

    __slots__ = ("_cond", "_var", "cost", "sigma", "step", "x")

    def __init__(self, x, variance, condition_number, step, cost, sigma):
        # condition_number: a number, or the (n, n) triangle R whose it is;
        # variance: an array, or (factor, h, v, active_idx, N): factor * h^2 * v
        # (v: the scaled variance, or the iteration's R^-1 whose squared row norms it is)
        # on the calibrated parameters (active_idx; None: all)
        s = object.__setattr__
        s(self, "x", x)
        s(self, "_var", variance)
        s(self, "_cond", condition_number)
        s(self, "step", step)
        s(self, "cost", cost)
        s(self, "sigma", sigma)

    @property
    def variance(self) -> np.ndarray:
        v = self._var
        if isinstance(v, tuple):
            factor, h, vs, idx, n = v
            if vs.ndim == 2:  # R^-1 of the iteration: its squared row norms
                vs = row_norms2(vs)
            v = (factor * (h * h)) * vs
            if idx is not None:
                full = np.full(n, np.nan)
                full[idx] = v
                v = full
            object.__setattr__(self, "_var", v)
        return v

    @property
    def condition_number(self) -> float:
        return formed_condition(self, "_cond")

    def __setattr__(self, name, value):
        raise AttributeError(f"cannot assign to field {name!r} (Iteration is read-only)")

    def __reduce__(self):
        return (Iteration, (self.x, self.variance, self.condition_number, self.step, self.cost,
                            self.sigma))

    def __repr__(self):
        return (f"Iteration(step={self.step!r}, cost={self.cost!r}, "
                f"condition_number={self.condition_number!r}, sigma={self.sigma!r})")
