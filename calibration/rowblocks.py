"""A tall matrix by blocks of rows: the memory design of the large fits (issue 43).

A motion capture's 100 000 poses of three points are a 900 000-row observation
matrix, 460 MB of doubles; its weighted, scaled or column-selected copies were as
large again each. The solver, the identifiability analysis and the fit statistics
take what they need from it a block of rows at a time (:data:`BLOCK_BYTES` at
most), never copying the whole:

* column norms (:func:`column_norms`), products (:func:`matvec`, :func:`gram`);
* the triangle ``R`` of the QR of a matrix given by blocks (:func:`stacked_qr`): the
  QR of each block stacked under the triangle of the blocks before it. An
  orthogonal map of the rows changes neither column norms, distances from spans,
  nor ``A^T b``, so that triangle serves wherever the QR of the whole did.

A matrix of one block (every fit of the station's sessions: a few thousand rows)
is taken whole, by the very operations that took it before: the same numbers to
the last bit. Larger ones differ at round-off only.
"""
from __future__ import annotations

import numpy as np
from scipy.linalg import lapack

#: the largest block of rows taken at a time (bytes of doubles)
BLOCK_BYTES = 8 << 20


def spans(rows: int, ncols: int) -> list[tuple[int, int]]:
    """``[(lo, hi), ...]``: the blocks of rows of a ``(rows, ncols)`` matrix of doubles,
    each at most :data:`BLOCK_BYTES` (at least one row); one where it fits whole."""
    step = max(1, BLOCK_BYTES // (8 * max(int(ncols), 1)))
    if rows <= step:
        return [(0, rows)]
    return [(lo, min(lo + step, rows)) for lo in range(0, rows, step)]


def rows_of(W, lo: int, hi: int, cols=None):
    """Rows ``lo:hi`` of ``W[:, cols]`` (``cols`` None: every column; an index array or
    a bool mask otherwise), as ``W[:, cols][lo:hi]`` has them (a copy where ``cols``
    is given, else a view)."""
    B = W[lo:hi] if (lo, hi) != (0, W.shape[0]) else W
    if cols is None:
        return B
    cols = np.asarray(cols)
    if cols.dtype == bool:
        return B[:, cols]
    return B.take(cols, axis=1)


def column_norms(W, cols=None, g=None) -> np.ndarray:
    """``||(G W[:, cols])[:, j]||`` (``g``: the diagonal of ``G``, a float or one per
    row; None: 1), as ``np.sqrt(np.einsum("ij,ij->j", A, A))`` of the whole ``A``."""
    rows = W.shape[0]
    n = W.shape[1] if cols is None else _count(cols)
    ss = None
    for lo, hi in spans(rows, n):
        B = scaled_rows(W, lo, hi, cols, g)
        s = np.einsum("ij,ij->j", B, B)
        ss = s if ss is None else ss + s
    if ss is None:
        return np.zeros(n)
    return np.sqrt(ss)


def scaled_rows(W, lo: int, hi: int, cols=None, g=None):
    """Rows ``lo:hi`` of ``G W[:, cols]`` (``W * g`` for a float ``g``, ``W * g[:, None]``
    for one per row)."""
    B = rows_of(W, lo, hi, cols)
    if g is None:
        return B
    if isinstance(g, float):
        return B * g
    return B * g[lo:hi, None]


def matvec(W, d, cols=None) -> np.ndarray:
    """``W[:, cols] @ d`` by blocks of rows."""
    rows = W.shape[0]
    n = W.shape[1] if cols is None else _count(cols)
    blocks = spans(rows, n)
    if len(blocks) == 1:
        return rows_of(W, 0, rows, cols) @ d
    out = np.empty(rows)
    for lo, hi in blocks:
        out[lo:hi] = rows_of(W, lo, hi, cols) @ d
    return out


def gram(W, cols=None, w=None) -> np.ndarray:
    """``A^T diag(w) A``, ``A = W[:, cols]`` (``w`` None: 1), by blocks of rows."""
    rows = W.shape[0]
    n = W.shape[1] if cols is None else _count(cols)
    out = np.zeros((n, n))
    for lo, hi in spans(rows, n):
        A = rows_of(W, lo, hi, cols)
        out += A.T @ (A if w is None else A * w[lo:hi, None])
    return out


def stacked_qr(block, blocks, ncols: int):
    """The LAPACK QR (``dgeqrf``: ``(qr, tau, work, info)``) of the last block of rows
    stacked under the triangle ``R`` of the QR of all the blocks before it: its upper
    ``(ncols, ncols)`` triangle is that of the QR of the blocks stacked whole (up to
    the signs of its rows). ``block(lo, hi)``: rows ``lo:hi`` of the matrix, a
    ``(hi - lo, ncols)`` array in Fortran order (which this may overwrite), for each
    ``(lo, hi)`` of ``blocks`` (:func:`spans`). One block: ``dgeqrf`` of that block."""
    R = None
    for k, (lo, hi) in enumerate(blocks):
        B = block(lo, hi)
        if R is not None:
            S = np.empty((R.shape[0] + B.shape[0], ncols), order="F")
            S[:R.shape[0]] = R
            S[R.shape[0]:] = B
            B = S
            del S
        out = lapack.dgeqrf(B, overwrite_a=1)
        del B
        if out[3] != 0 or k == len(blocks) - 1:
            return out
        R = np.triu(out[0][:min(ncols, out[0].shape[0])])
        del out  # (the block's rows, not kept while the next is made)
    return lapack.dgeqrf(np.zeros((0, ncols), order="F"))  # no blocks


def triangle(block, blocks, ncols: int) -> np.ndarray:
    """The upper triangle ``R`` (``(min(rows, ncols), ncols)``) of the QR of the
    matrix whose blocks of rows ``block(lo, hi)`` gives (:func:`stacked_qr`)."""
    qr = stacked_qr(block, blocks, ncols)[0]
    return np.triu(qr[:min(qr.shape[0], ncols)])


def _count(cols) -> int:
    cols = np.asarray(cols)
    return int(cols.sum()) if cols.dtype == bool else len(cols)
