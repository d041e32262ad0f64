"""After the sequential test of :func:`calibration.identifiability.classify` has dropped
a dependent column: which column of a nearly dependent set is kept (a dependent column
takes the place of a kept one that is nearly in the span of the others,
:func:`_exchange`), and the kept columns that are together still nearly dependent
(:func:`_jointly_dependent`), judged on the triangle of one QR."""
from __future__ import annotations

import numpy as np
from scipy.linalg import lapack


#: a dependent column takes the place of a kept one whose coefficient in it is this many
#: times larger than its own (:func:`_exchange`): the kept one is within 1 % of the
#: span of the others
EXCHANGE = 100.0


def _exchange(T0, idx0, use, dep, rdiag, rank_tol: float) -> bool:
    """Exchange kept and dependent columns until no kept one is nearly dependent on the
    others; True if any was exchanged (``use``, ``dep``, ``rdiag`` updated in place).

    A structural dependency survives a calibration: a link's translations span three
    directions, so joint i's translation along its axis and joint i+1's three are
    always dependent. At the nominal the axis may be joint i+1's x exactly: the two
    columns are equal and the one judged first is kept. Calibrated (the station's own
    export read again), the axis is a milliradian off: the sequential QR keeps both
    and drops joint i+1's z, whose coefficients on them are a thousand. The kept set is
    then nearly singular (the solver's condition 1e8 to 1e16) and the fit crawls along
    it. Where a dependent column's coefficient on a kept one exceeds :data:`EXCHANGE`
    (in unit columns), the two change places: the kept set's volume grows by that
    coefficient (the swap of a strong rank-revealing QR), and the set kept is the
    nominal's again. A nominal's dependencies have coefficients of order one to a few
    tens (a plane absorbing a translation, a parallel mechanism's legs), where
    nothing changes. Only numerically dependent columns (``rdiag <= rank_tol``) take
    part. ``T0``: the unit columns ``idx0`` in judging order, or their QR triangle."""
    order = idx0.tolist()
    kept = [k for k, i in enumerate(order) if use[i]]
    cand = [k for k, i in enumerate(order) if dep[i] and rdiag[i] <= rank_tol]
    if not cand:
        return False
    changed = False
    for _ in range(4 * len(order)):
        best = None
        A = T0[:, kept]
        for k in cand:
            c = np.linalg.lstsq(A, T0[:, k], rcond=None)[0]
            a = np.abs(c)
            m = float(a.max()) if a.size else 0.0
            if m > EXCHANGE and (best is None or m > best[0]):
                # of coefficients within a percent of the largest, the last judged goes
                i = int(np.flatnonzero(a >= 0.99 * m)[-1])
                best = (m, k, i)
        if best is None:
            break
        _, k, i = best
        out = kept[i]
        kept[i:i + 1] = []
        kept = sorted(kept + [k])
        cand = [c for c in cand if c != k] + [out]
        use[order[k]], dep[order[k]] = True, False
        use[order[out]], dep[order[out]] = False, True
        changed = True
    if changed:
        d = np.abs(np.linalg.qr(T0[:, kept], mode="r").diagonal())
        rdiag[[order[k] for k in kept]] = d
        A = T0[:, kept]
        for k in cand:
            e = T0[:, k] - A @ np.linalg.lstsq(A, T0[:, k], rcond=None)[0]
            rdiag[order[k]] = float(np.sqrt(e @ e))
    return changed


def _well_conditioned(R, rank_tol: float) -> bool:
    """Is the smallest singular value of the triangle ``R`` of unit columns clearly
    above ``rank_tol``? (A bound from ``R``'s inverse: ``1 / ||R^-1||_F``.)"""
    Rinv, info = lapack.dtrtri(R)
    if info:
        return False
    s = float(np.sqrt(np.einsum("ij,ij->", Rinv, Rinv)))
    return s == s and s * rank_tol < 1.0


def _jointly_dependent(T0, idx0, use, rank_tol: float, triangular: bool) -> list[int]:
    """The kept columns (``use``) to drop until the kept set's smallest singular value
    (of its unit columns) is above ``rank_tol``: each time, of the columns that take part
    in the near-dependency (a weight at least a hundredth of the largest in its singular
    vector), the one judged last, as :func:`classify` keeps the first of two dependent
    columns. ``T0``: the unit columns ``idx0`` in judging order, or (``triangular``) their
    QR triangle, which serves as it is while every column is kept."""
    pos = [k for k, i in enumerate(idx0.tolist()) if use[i]]
    out = []
    while len(pos) > 1:
        A = T0[:, pos]
        if triangular and len(pos) == T0.shape[1]:
            Rk = A                                  # (T0's own triangle)
        elif A.shape[0] >= A.shape[1]:
            Rk = np.linalg.qr(A, mode="r")
        else:
            Rk = A                                  # (not tall: the SVD below decides)
        if Rk.shape[0] == Rk.shape[1] and _well_conditioned(np.asarray(Rk, order="F"), rank_tol):
            break
        _, s, vt = np.linalg.svd(Rk)
        if s[-1] > rank_tol:
            break
        v = np.abs(vt[-1])
        k = int(np.flatnonzero(v >= 0.01 * v.max())[-1])
        out.append(int(idx0[pos[k]]))
        del pos[k]
    return out
