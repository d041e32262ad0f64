"""Identifiability of calibrated parameters by QR of the scaled observation
matrix, in parameter order (report section 5).

The columns of ``W`` are error-weighted (``G W``) and scaled to unit norm
(``H``), then factored ``W = Q R`` without pivoting, so that ``|R[j, j]|`` is the
distance of column j from the span of the columns before it. A parameter is

* identifiable where that distance is clearly non-zero;
* not identifiable, **no influence**, where its whole column is zero: the
  measurements do not depend on it, so leaving it at a wrong nominal value
  does not bias the others;
* not identifiable, **influences the model**, where its column is a
  combination of earlier ones: a wrong nominal value is absorbed by (biases)
  the others.

"Zero" has two parts. The numerical part is ``rank_tol`` relative to the
largest column. The statistical part applies at the solution only
(``residual`` given): several dependencies hold exactly only where the model
fits the data (the scale of a self-calibration, a plane absorbing a
translation); with noisy data those columns, or their independent parts, are
of the order of the residual. A column part no larger than ``kappa`` times the
weighted residual norm (SI units per parameter unit) carries no information
beyond the noise and is judged zero. In terms of the estimate this flags a
parameter whose standard deviation would exceed ``1/(kappa*sqrt(rows))`` in SI
units (rad, m, or the ratio itself for a transmission ratio).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.linalg import lapack

from calibration import rowblocks
from calibration.dependent_columns import _exchange, _jointly_dependent

IDENTIFIABLE = "identifiable"
NO_INFLUENCE = "no influence"
INFLUENCES = "influences the model"
FIXED = "fixed"


@dataclass(frozen=True)
class ParameterStatus:
    name: str
    identifiable: bool
    influences_model: bool  # meaningful where not identifiable
    r_diag: float  # |R[j, j]| of the scaled, weighted matrix (1 = independent)
    column_norm: float  # ||G W[:, j]|| (weighted, per parameter unit)
    # kept at its given value (``SolverOptions.fixed``), never a candidate; then
    # ``influences_model`` says whether its column is above the zero floor
    fixed: bool = False

    @classmethod
    def of(cls, name, identifiable, influences_model, r_diag, column_norm, fixed=False):
        """The same as the constructor, without its per-field checks of a frozen
        dataclass (half the time; the solver makes one per parameter per solve)."""
        s = object.__new__(cls)
        s.__dict__.update(name=name, identifiable=identifiable,
                          influences_model=influences_model, r_diag=r_diag,
                          column_norm=column_norm, fixed=fixed)
        return s

    @property
    def label(self) -> str:
        if self.identifiable:
            return IDENTIFIABLE
        if self.fixed:
            return f"{FIXED}, {INFLUENCES if self.influences_model else NO_INFLUENCE}"
        return INFLUENCES if self.influences_model else NO_INFLUENCE


def analyze(W: np.ndarray, names, *, weights: np.ndarray | None = None,
            candidates: np.ndarray | None = None, residual: np.ndarray | None = None,
            rank_tol: float = 1e-8, kappa: float = 3.0, order=None) -> list[ParameterStatus]:
    """Classify every parameter (see module doc).

    W:          ``(rows, N)`` observation matrix.
    weights:    ``(rows,)`` error weights (the diagonal of L), default 1.
    candidates: ``(N,)`` bool, the parameters that may be calibrated at all
                (others are reported not identifiable, no influence, and do not
                enter the QR).
    residual:   ``(rows,)`` residual at the solution, enabling the statistical test.
    order:      the order in which the columns are judged (a permutation of ``range(N)``;
                default the parameter order): of two dependent parameters the one
                judged first is kept (:attr:`calibration.model.MeasurementModel.identify_order`).
    """
    ident, dep, rdiag, norms = classify(W, weights=weights, candidates=candidates,
                                        residual=residual, rank_tol=rank_tol, kappa=kappa,
                                        order=order)
    return [ParameterStatus(*row) for row in zip(names, ident.tolist(), dep.tolist(),
                                                 rdiag.tolist(), norms.tolist())]


def zero_floor(norms, rank_tol: float, candidates=None, rg=None, kappa: float = 0.0):
    """The floor below which :func:`classify` takes a column of norm ``norms[j]`` for
    zero: ``rank_tol`` times the largest norm (of the ``candidates``' columns where
    given; 0 where there is none), raised to ``kappa`` times the weighted residual's
    norm where ``rg`` is given. The solver's checks (:mod:`calibration.solver.rounds`,
    :mod:`calibration.solver.result`) use the same."""
    if candidates is None:
        floor = rank_tol * norms.max() if norms.size else 0.0
    elif candidates.all():
        floor = rank_tol * norms.max()
    else:  # (a few columns: a list is faster than numpy's max with where=; NaN as there)
        vals = norms[candidates].tolist()
        total = sum(vals)
        floor = rank_tol * (max(vals, default=0.0) if total == total else math.nan)
    if rg is not None:
        floor = max(floor, kappa * math.sqrt(float(rg @ rg)))
    return floor


def column_floor(Wg, rank_tol: float, candidates=None, rg=None,
                 kappa: float = 0.0, row_scale=None) -> tuple[np.ndarray, float]:
    """The column norms of the weighted matrix ``Wg`` (``row_scale``: of ``G Wg``, ``G``
    its diagonal, a float or one per row, without forming it) and their
    :func:`zero_floor`."""
    norms = rowblocks.column_norms(Wg, g=row_scale)
    return norms, zero_floor(norms, rank_tol, candidates, rg, kappa)


def classify(W: np.ndarray, *, weights: np.ndarray | None = None,
             candidates: np.ndarray | None = None, residual: np.ndarray | None = None,
             rank_tol: float = 1e-8, kappa: float = 3.0, return_r: bool = False,
             order=None, row_scale=None):
    """:func:`analyze` as arrays ``(identifiable, influences, r_diag, column_norm)``,
    each ``(N,)``; ``W`` may also be given already weighted (``weights`` None), or
    with its rows' scale ``row_scale`` (``sqrt(weights)``: a float, or one per row).
    ``return_r``: append the triangle ``R`` of the QR of the unit columns of
    the identifiable parameters (in order), or None where some candidate
    column was dependent (then no single QR covers them).

    The sequential test "distance of column j from the span of the earlier
    *kept* columns" is one unpivoted Householder QR of the unit columns in
    parameter order: ``|R[j, j]|`` is the distance of column j from the span of
    all earlier columns. Up to the first dependent column they are all kept,
    so the diagonal is the answer there; the dependent column is then left out
    (the span of the kept ones projected away) and the QR resumes on the
    columns after it. One QR of the tall matrix in any case; the restarts
    after dependent columns work on its ``(q, q)`` triangle (same distances).
    ``order``: judge the columns in this order instead (:func:`analyze`); ``R`` is
    then None.

    The weighted, ordered unit columns are never formed whole: a large ``W`` is
    taken a block of rows at a time (:mod:`calibration.rowblocks`), the triangle of
    their QR made from the blocks' (the same numbers where ``W`` is one block).
    """
    W = np.asarray(W, dtype=float)
    n = W.shape[1]
    perm = None
    if order is not None and not np.array_equal(order, np.arange(n)):
        perm = np.asarray(order, dtype=np.intp)
    if weights is not None:
        g = np.sqrt(np.asarray(weights, dtype=float))
    elif row_scale is not None:
        g = row_scale if isinstance(row_scale, float) else np.asarray(row_scale, dtype=float)
    else:
        g = None
    cand = None if candidates is None else np.asarray(candidates, bool)
    if perm is not None and cand is not None:
        cand = cand[perm]
    rg = None
    if residual is not None:
        rg = np.asarray(residual, dtype=float) if g is None else g * residual
    out = _classify(W, g, perm, cand, rg, rank_tol, kappa, return_r and perm is None)
    if perm is not None:
        inv = np.argsort(perm)
        out = tuple(a[inv] for a in out[:4])
        return (*out, None) if return_r else out
    return out if return_r else out[:4]


def _classify(W, g, perm, cand, rg, rank_tol, kappa, return_r):
    """:func:`classify` of the columns ``perm`` (None: all, in order) of ``G W``
    (``g``: the diagonal of ``G``, None: 1); ``cand``, ``rg`` in that order and
    weighted: ``(identifiable, influences, r_diag, column_norm, R)``."""
    rows, n = W.shape
    blocks = rowblocks.spans(rows, n)
    whole = None  # the one block of a matrix taken whole

    def block(lo, hi):
        if perm is None:
            B = W[lo:hi]
            if g is None:
                return B
            return B * g if isinstance(g, float) else B * g[lo:hi, None]
        B = W[lo:hi][:, perm]  # (a copy, as W[:, perm] lays it out; scaled in place)
        if g is not None:
            B *= g if isinstance(g, float) else g[lo:hi, None]
        return B

    if len(blocks) == 1:
        whole = block(0, rows)
        norms, floor = column_floor(whole, rank_tol, cand, rg, kappa)
    else:
        ss = np.zeros(n)
        for lo, hi in blocks:
            B = block(lo, hi)
            ss += np.einsum("ij,ij->j", B, B)
        norms = np.sqrt(ss)
        floor = zero_floor(norms, rank_tol, cand, rg, kappa)
    use = norms > floor if cand is None else cand & (norms > floor)
    rdiag = np.zeros(n)
    dep = np.zeros(n, bool)
    R = None
    if use.all():
        idx, nidx = np.arange(n), norms
    else:
        idx = np.flatnonzero(use)
        nidx = norms[idx]

    def unit(B):
        # the unit columns in Fortran order, as LAPACK takes them (no copy on the way;
        # in place where B is a Fortran-ordered copy of W's rows: the same numbers)
        if use.all():
            own = B.flags.f_contiguous and not np.may_share_memory(B, W)
            return np.divide(B, norms, out=B if own else np.empty(B.shape, order="F"))
        return np.divide(B[:, idx], nidx, out=np.empty((B.shape[0], idx.size), order="F"))

    if rows > idx.size > 0:
        # distances and projections do not change under an orthogonal map of
        # the rows: the triangle of one QR of T stands for T (no dependent
        # column: its diagonal is the answer; else each restart below works
        # on q rows, not on all of them)
        q = idx.size
        if whole is not None:
            U1, whole = unit(whole), None
            T = rowblocks.stacked_qr(lambda lo, hi: U1, blocks, q)[0][:q] * _upper(q)
            del U1
        else:
            T = rowblocks.stacked_qr(lambda lo, hi: unit(block(lo, hi)), blocks, q)[0]
            T = T[:q] * _upper(q)
        tri = True  # T is its own R (a QR of it would give it back unchanged)
    elif idx.size:  # not tall (rare, and small): restarts below on T as it always was
        T = np.ascontiguousarray(unit(whole if whole is not None else block(0, rows)))
        tri = False
    else:  # no column to judge
        T, tri = np.empty((rows, 0)), False
    del whole
    T0, idx0, tri0 = T, idx, tri  # (for the checks below: T0 is its triangle where tri0)
    basis = None  # orthonormal basis of the kept columns before idx[0], once one was dropped
    while idx.size:
        if tri:
            d, qr, tri = np.abs(T.diagonal()), T, False
        else:
            d, qr = _r_diagonal(T)
        bad = (d <= rank_tol) | (d * nidx <= floor)
        if not bad.any():
            rdiag[idx] = d
            if return_r and basis is None and qr is not None:
                q = len(idx)
                R = qr[:q, :q] * _upper(q)
            break
        j = int(bad.argmax())  # the first dependent column
        rdiag[idx[:j + 1]] = d[:j + 1]
        dep[idx[j]] = True
        if j:
            Qj = np.linalg.qr(T[:, :j])[0]
            basis = Qj if basis is None else np.column_stack([basis, Qj])
        idx, nidx, T = idx[j + 1:], nidx[j + 1:], T[:, j + 1:]
        if idx.size and basis is not None:
            for _ in range(2):  # re-orthogonalised, as classical Gram-Schmidt needs
                T = T - basis @ (basis.T @ T)
    use &= ~dep
    if dep.any() and use.any() and _exchange(T0, idx0, use, dep, rdiag, rank_tol):
        R = None
    if use.any():
        # each kept column is clearly off the span of the earlier ones; several of them
        # together may still be nearly dependent: dropped, the last judged first
        for j in _jointly_dependent(T0, idx0, use, rank_tol, tri0):
            use[j] = False
            dep[j] = True
            R = None
    return use, dep, rdiag, norms, R


_UPPER: dict[int, np.ndarray] = {}


def _upper(q: int) -> np.ndarray:
    """The 0/1 mask of the upper triangle of a ``(q, q)`` matrix (cached)."""
    m = _UPPER.get(q)
    if m is None:
        m = _UPPER[q] = np.asfortranarray(np.triu(np.ones((q, q))))
    return m


def _r_diagonal(T: np.ndarray):
    """``|R[j, j]|`` of the unpivoted QR of ``T`` (0 past the row count) and the
    LAPACK QR (None where ``T`` is not tall)."""
    m, q = T.shape
    if m >= q:
        if not q:
            return np.zeros(0), None
        qr = lapack.dgeqrf(T)[0]
        return np.abs(qr.diagonal()), qr
    d = np.zeros(q)
    if m:
        d[:m] = np.abs(lapack.dgeqrf(T)[0].diagonal())
    return d, None


def minimum_poses(n_identifiable: int, p: int) -> int:
    """Recommended pose count, eq. 60: ``m >= 5 N_R / p``."""
    return int(np.ceil(5 * n_identifiable / max(p, 1)))


def absorbed(W: np.ndarray, weights: np.ndarray | None, identifiable, influences,
             tol: float = 1e-3) -> dict[int, list[int]]:
    """Which identifiable parameters absorb the held ones that influence the model.

    A parameter classified "influences the model" has a column that is (near) a
    combination of the identifiable ones: ``w_h ~ W_R c``. Held at its start value, its
    error moves each identifiable parameter j by ``c_j`` times that error: the value
    of j is then j's own plus that share, a combination, and its std is the
    combination's. Returns ``{j: [h, ...]}`` for the identifiable j with ``|c_j| >
    tol`` in unit-scaled columns (indices into the columns of ``W``)."""
    W = np.asarray(W, dtype=float)
    ident = np.flatnonzero(np.asarray(identifiable, bool))
    held = np.flatnonzero(np.asarray(influences, bool) & ~np.asarray(identifiable, bool))
    out: dict[int, list[int]] = {}
    if not ident.size or not held.size:
        return out
    if len(rowblocks.spans(*W.shape)) == 1:
        if weights is not None:
            W = W * np.sqrt(np.asarray(weights, dtype=float))[:, None]
        norms = np.linalg.norm(W, axis=0)
        A = W[:, ident] / np.where(norms[ident] > 0, norms[ident], 1.0)
        B = W[:, held] / np.where(norms[held] > 0, norms[held], 1.0)
        C = np.linalg.lstsq(A, B, rcond=None)[0]           # (identifiable, held)
    else:
        C = _absorbed_by_blocks(W, weights, ident, held)
    for a, j in enumerate(ident):
        hs = [int(held[b]) for b in np.flatnonzero(np.abs(C[a]) > tol)]
        if hs:
            out[int(j)] = hs
    return out


def _absorbed_by_blocks(W, weights, ident, held) -> np.ndarray:
    """The coefficients of :func:`absorbed` from the triangle of the QR of the unit
    columns ``[A B]`` (``A`` the identifiable ones, ``B`` the held), made a block of
    rows at a time: with ``A = Q1 R11``, ``B = Q1 R12 + Q2 R22`` the least-squares
    (minimum-norm) solution of ``A C ~ B`` is that of ``R11 C ~ R12``, with the same
    singular values and so the same cut-off."""
    cols = np.r_[ident, held]
    g = None if weights is None else np.sqrt(np.asarray(weights, dtype=float))
    rows, k = W.shape[0], len(ident)
    blocks = rowblocks.spans(rows, len(cols))
    norms = rowblocks.column_norms(W, cols, g)
    norms = np.where(norms > 0, norms, 1.0)
    R = rowblocks.triangle(lambda lo, hi: np.divide(
        rowblocks.scaled_rows(W, lo, hi, cols, g), norms,
        out=np.empty((hi - lo, len(cols)), order="F")), blocks, len(cols))
    rcond = np.finfo(float).eps * max(rows, k)  # (lstsq's default for A itself)
    return np.linalg.lstsq(R[:k, :k], R[:k, k:], rcond=rcond)[0]
