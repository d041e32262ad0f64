"""The weighted hat matrix of the linearized problem at a solution, ``H = A (A^T A)^+ A^T``
with ``A = sqrt(w) W_R`` (the identifiable columns, scaled to unit length): its diagonal
(the leverages), the leverage of rows not in the fit, and an orthonormal basis ``U``
with ``H = U U^T``. A tall matrix is taken 8 MiB of rows at a time
(:mod:`calibration.rowblocks`), never copied whole. The statistics built on them are
:mod:`calibration.quality` and :mod:`calibration.pose_quality`.
"""
from __future__ import annotations

import numpy as np

from calibration import rowblocks


def _scaled_svd(W: np.ndarray, weights: np.ndarray, active: np.ndarray, basis: bool = True,
                into=None):
    """Column norms and the thin SVD (rank from the singular values) of the
    weighted, column-scaled ``A = sqrt(w) W_R / norms``: ``(norms, U, sv, Vt)``
    (``basis`` False: ``U`` None where ``A`` is large; ``into``: ``W`` itself, where
    a large one's ``U`` may be written, see :func:`_large_svd`)."""
    active = np.asarray(active, bool)
    if len(rowblocks.spans(W.shape[0], int(active.sum()))) > 1:
        return _large_svd(W, weights, active, basis, into)
    A = W[:, active] * np.sqrt(weights)[:, None]
    norms = np.linalg.norm(A, axis=0)
    norms = np.where(norms > 0, norms, 1.0)
    U, sv, Vt = np.linalg.svd(A / norms, full_matrices=False)
    keep = sv > sv[0] * 1e-10 if sv.size and sv[0] > 0 else np.zeros(sv.size, bool)
    return norms, U[:, keep], sv[keep], Vt[keep]


def _large_svd(W, weights, active, basis: bool, into=None):
    """:func:`_scaled_svd` of a matrix of many blocks of rows (:mod:`calibration.rowblocks`),
    never formed whole: ``sv`` and ``Vt`` from the SVD of the triangle ``R`` of the QR of
    ``A`` (``A = Q R``, ``R = U_R S V^T``: ``A``'s own), ``U = A V S^-1`` (the kept
    columns only) block by block where ``basis``, else None (its error is round-off
    times the condition number of the kept ``A``). ``into`` (``W``, C order): ``U`` is
    written over the first columns of its rows, each block after it was read."""
    g = np.sqrt(np.asarray(weights, dtype=float))
    n = int(active.sum())
    blocks = rowblocks.spans(W.shape[0], n)
    norms = rowblocks.column_norms(W, active, g)
    norms = np.where(norms > 0, norms, 1.0)

    def unit(lo, hi):
        return np.divide(rowblocks.scaled_rows(W, lo, hi, active, g), norms,
                         out=np.empty((hi - lo, n), order="F"))

    R = rowblocks.triangle(unit, blocks, n)
    sv, Vt = np.linalg.svd(R, full_matrices=False)[1:]
    keep = sv > sv[0] * 1e-10 if sv.size and sv[0] > 0 else np.zeros(sv.size, bool)
    sv, Vt = sv[keep], Vt[keep]
    U = None
    if basis:
        M = Vt.T / sv
        if into is not None and into.flags.c_contiguous and into.shape[1] >= len(sv):
            U = into[:, :len(sv)]
        else:
            U = np.empty((W.shape[0], len(sv)))
        for lo, hi in blocks:
            U[lo:hi] = unit(lo, hi) @ M
    return norms, U, sv, Vt


def leverage(W: np.ndarray, weights: np.ndarray, active: np.ndarray) -> np.ndarray:
    """Diagonal of the weighted hat matrix ``A (A^T A)^+ A^T``, ``A = sqrt(w) W_R``
    (columns scaled first; rank from the singular values)."""
    if not np.any(active):
        return np.zeros(W.shape[0])
    active = np.asarray(active, bool)
    blocks = rowblocks.spans(W.shape[0], int(active.sum()))
    if len(blocks) == 1:
        U = _scaled_svd(W, weights, active)[1]
        return np.einsum("ij,ij->i", U, U)
    # U's rows' squared norms a block at a time, U never whole
    g = np.sqrt(np.asarray(weights, dtype=float))
    norms, _, sv, Vt = _scaled_svd(W, weights, active, basis=False)
    M = Vt.T / sv
    h = np.empty(W.shape[0])
    for lo, hi in blocks:
        Z = (rowblocks.scaled_rows(W, lo, hi, active, g) / norms) @ M
        h[lo:hi] = np.einsum("ij,ij->i", Z, Z)
    return h


def prediction_leverage(W: np.ndarray, weights: np.ndarray, active: np.ndarray,
                        W_new: np.ndarray, weights_new: np.ndarray) -> np.ndarray:
    """For rows not in the fit (held out, or left out of it): ``w J (A^T A)^+ J^T``
    with ``A = sqrt(w) W_R`` of the fit's rows, the variance of the row's prediction
    from the fitted parameters in units of the row's own noise variance. A fit
    row's leverage ``h`` is this ``h / (1 - h)`` from the fit without it."""
    W_new = np.atleast_2d(np.asarray(W_new, dtype=float))
    if not np.any(active):
        return np.zeros(W_new.shape[0])
    norms, _, sv, Vt = _scaled_svd(W, weights, active, basis=False)
    B = W_new[:, active] * np.sqrt(weights_new)[:, None] / norms
    Z = (B @ Vt.T) / sv
    return np.einsum("ij,ij->i", Z, Z)


def hat_basis(W: np.ndarray, weights: np.ndarray, active: np.ndarray, *,
              overwrite: bool = False) -> np.ndarray:
    """Orthonormal basis ``U (rows, rank)`` of the weighted, scaled identifiable columns:
    the weighted hat matrix is ``U U^T`` (its diagonal :func:`leverage`).
    ``overwrite``: ``W`` (C order) is not needed after this; a large one then holds
    ``U`` in its first columns (a view of it, no second matrix of its rows)."""
    if not np.any(active):
        return np.zeros((W.shape[0], 0))
    return _scaled_svd(W, weights, active, into=W if overwrite else None)[1]
