"""The factorization of an iteration's scaled, weighted system and the solves on it.

:class:`Scaled` factors ``[G W_R H, G r]`` once per iteration (one Householder QR
of a tall matrix, made a block of rows at a time: :mod:`calibration.rowblocks`) and
gives from that one factorization the damped step (eq. 48) for every lambda tried
at the point, the variance (eq. 52) and the condition number;
:func:`clearly_identifiable` reads the identifiability classification off it.

What it saves (each measured when it was added):

- one QR per iteration, not one per damping tried: the damped step is the small
  ``[R; lambda I]`` problem (:meth:`Scaled.step`), and a damping below round-off
  against every singular value (:data:`ROUNDOFF_DAMPING`) is the undamped
  triangle solve, one LAPACK call instead of a second QR;
- the singular values of ``R``: where ``||R||_F ||R^-1||_F`` (the Frobenius
  bound of the condition number) is below 1e12 they are not needed for the
  step, and are formed only when the condition number is read
  (:meth:`Scaled.cond_below`, :attr:`Scaled.cond_or_triangle`,
  :func:`formed_condition`);
- memory: ``A`` is never formed whole (the block-wise QR of
  :func:`calibration.rowblocks.stacked_qr`);
- classify's own QR at the start and at the solution, where this one shows
  every parameter clearly identifiable (:func:`clearly_identifiable`).
"""
from __future__ import annotations

import math

import numpy as np
from scipy.linalg import lapack

from calibration import rowblocks

#: a damping ``lambda^2`` at most this fraction of the smallest singular value's
#: square changes the step only at round-off (:meth:`Scaled.step` then solves the
#: undamped triangle: one LAPACK call instead of a second QR)
ROUNDOFF_DAMPING = 2.0 ** -53

geqrf, gesvd, trtrs, trtri = lapack.dgeqrf, lapack.dgesvd, lapack.dtrtrs, lapack.dtrtri
_MASKS: dict[int, tuple] = {}


def cond_of(sv) -> float:
    """The condition number from singular values in decreasing order."""
    s0, smin = float(sv[0]), float(sv[-1])
    return s0 / smin if smin > 0 else math.inf


def formed_condition(record, name: str) -> float:
    """The condition number held in ``record``'s attribute ``name``: a number, or the
    triangle whose it is (:attr:`Scaled.cond_or_triangle`), formed from its singular
    values on this first read and kept in its place (``record`` read-only, as
    :class:`Iteration` and :class:`~calibration.solver.result.CalibrationResult`)."""
    c = getattr(record, name)
    if isinstance(c, np.ndarray):
        c = cond_of(gesvd(c, compute_uv=0)[1])
        object.__setattr__(record, name, c)
    return c


def masks(n: int):
    """Per column count ``n`` (cached, Fortran order): the 0/1 mask of the upper
    triangle of an ``(n, n + 1)`` block (its last column, ``Q^T b``, kept whole)
    and the ``(2n, n + 1)`` array ``[0 0; I 0]`` that becomes ``[R c; lambda I 0]``."""
    m = _MASKS.get(n)
    if m is None:
        aug = np.zeros((2 * n, n + 1), order="F")
        aug[np.arange(n) + n, np.arange(n)] = 1.0
        m = _MASKS[n] = (np.asfortranarray(np.triu(np.ones((n, n + 1)))), aug)
    return m


class Scaled:
    """One iteration's scaled, weighted least-squares problem ``A z ~ b`` with
    ``A = G W_R H`` (``g = diag(G)`` a float or per row) and ``b = G r``,
    factored once and reused for every damping tried at that point.

    Tall ``A`` (the normal case): one Householder QR of ``[A b]`` gives
    ``R`` and ``c = Q^T b``; the damped step (eq. 48) is the least-squares
    solution of ``[R; lambda I] z = [c; 0]`` (one small QR), the variance
    (eq. 52) the row norms of ``R^-1``, the condition number the singular values
    of ``R`` (those of ``A``). Where ``R`` is numerically singular, or ``A`` not
    tall, the same quantities come from an SVD with the singular values below
    ``1e-15 s_max`` cut (a pseudo-inverse), as the normal equations would.

    ``key`` identifies the matrix factored (the run's observation matrix, which this
    does not keep); ``A`` is made from ``WA``'s columns ``cols`` (None: all) a block of
    rows at a time (:mod:`calibration.rowblocks`), never whole."""

    __slots__ = ("R", "Rc", "Rinv", "_sv", "cost", "g", "h", "key", "n", "r", "rf2", "rinv2",
                 "rows", "sigma", "stated", "svd", "vs")

    def __init__(self, key, sigma, WA, h, g, r, cols=None):
        rows = WA.shape[0]
        n = WA.shape[1] if cols is None else len(cols)
        self.key, self.sigma, self.h, self.g, self.n, self.r = key, sigma, h, g, n, r
        self.rows = rows
        self.stated = None  # this point factored at the stated sigma (Stepping._record)
        scalar = isinstance(g, float)
        self.svd = self.Rinv = self.vs = self._sv = None
        self.rinv2 = math.inf  # ||R^-1||_F^2 (>= 1 / s_min^2) where known
        self.rf2 = math.inf  # ||R||_F^2 (>= s_max^2) where that is
        if rows <= n:
            WA = rowblocks.rows_of(WA, 0, rows, cols)
            A = WA * (h * g) if scalar else (WA * h) * g[:, None]
            b = r * g
            self.cost = 0.5 * float(b @ b)
            U, sv, Vt = np.linalg.svd(A, full_matrices=False)
            self._sv, self.svd = sv, (Vt, U.T @ b)
            self.Rc = self.R = None
            return
        b = np.multiply(r, g)
        self.cost = 0.5 * float(b @ b)

        def block(lo, hi):
            Ab = np.empty((hi - lo, n + 1), order="F")
            A = rowblocks.rows_of(WA, lo, hi, cols)
            if scalar:
                np.multiply(A, h * g, out=Ab[:, :n])
            else:
                np.multiply(A, h, out=Ab[:, :n])
                Ab[:, :n] *= g[lo:hi, None]
            Ab[:, n] = b[lo:hi]
            return Ab

        qr = rowblocks.stacked_qr(block, rowblocks.spans(rows, n + 1), n + 1)[0]
        # [R c] with R upper triangular and c = Q^T b (Fortran order: R contiguous)
        Rc = self.Rc = qr[:n] * masks(n)[0]
        R = self.R = Rc[:, :n]
        # Clearly regular R (the normal case): ||R||_F ||R^-1||_F bounds the
        # condition number from above; below 1e12 the singular values (those
        # that decide on the pseudo-inverse below, cut at 1e-15 s_max) are not
        # needed now, and are computed only if asked for (condition number).
        Rinv, info = trtri(R)
        if info == 0:
            rf, vf = R.ravel(order="K"), Rinv.ravel(order="K")
            rf2, rinv2 = float(rf @ rf), float(vf @ vf)
            if rf2 * rinv2 < 1e24:  # also False for NaN
                self.Rinv = Rinv  # (the variance, its row norms, when first asked for)
                self.rf2, self.rinv2 = rf2, rinv2
                return
        sv, info = gesvd(R, compute_uv=0)[1::2]
        svl = sv.tolist()
        s0, smin = svl[0], svl[-1]
        if info != 0 or not math.isfinite(s0):
            raise np.linalg.LinAlgError("SVD did not converge")
        self._sv = sv
        if not smin > s0 * 1e-15:  # singular: pseudo-inverse through the SVD of R
            U, _sv, Vt = np.linalg.svd(R)
            self.svd = (Vt, U.T @ Rc[:, n])

    @property
    def sv(self):
        """Singular values of ``A`` (those of ``R``), computed when first asked for."""
        if self._sv is None:
            self._sv = gesvd(self.R, compute_uv=0)[1]
        return self._sv

    @property
    def s0(self) -> float:
        return float(self.sv[0])

    @property
    def smin(self) -> float:
        return float(self.sv[-1])

    @property
    def cond(self) -> float:
        return cond_of(self.sv)

    def cond_below(self, limit: float) -> bool:
        """Is the condition number below ``limit``? From the bound
        ``||R||_F ||R^-1||_F`` where that decides, without the singular values."""
        if self.rf2 * self.rinv2 < limit * limit:
            return True
        return self.cond < limit

    @property
    def cond_or_triangle(self):
        """The condition number where the singular values are known, else the
        triangle ``R`` whose it is (:func:`formed_condition` forms it when read)."""
        return self.R if self._sv is None and self.R is not None else self.cond

    def step(self, lam2):
        """Scaled damped step ``z`` (``d_R = h z``) for ``lambda^2 = lam2``."""
        if self.svd is not None:
            sv = self.sv
            Vt, Ub = self.svd
            if lam2 > 0:
                filt = sv / (sv * sv + lam2)
            else:
                filt = np.divide(1.0, sv, out=np.zeros_like(sv), where=sv > sv[0] * 1e-15)
            return Vt.T @ (filt * Ub)
        n = self.n
        # (lam2 = 0 without the bound: 0 * inf is NaN, undamped)
        if lam2 * self.rinv2 > ROUNDOFF_DAMPING:
            M = masks(n)[1] * math.sqrt(lam2)
            M[:n] = self.Rc
            qr = geqrf(M, overwrite_a=1)[0]
            return trtrs(qr[:n, :n], qr[:n, n])[0]
        # undamped, or a damping below round-off against every singular value
        # (lambda^2 / s_min^2 <= lambda^2 ||R^-1||_F^2): the Gauss-Newton step
        return trtrs(self.R, self.Rc[:, n])[0]

    def _image(self, z):
        """``A z`` and ``b`` in the basis where ``A`` is triangular (or diagonal)."""
        if self.svd is None:
            return self.R @ z, self.Rc[:, self.n]
        return self.sv * (self.svd[0] @ z), self.svd[1]

    def predicted(self, z) -> float:
        """The cost decrease the linear model predicts for the step ``z``:
        ``0.5 (||b||^2 - ||b - A z||^2)``."""
        v, c = self._image(z)
        return float(v @ (c - 0.5 * v))

    def slope(self, z) -> float:
        """``-d cost(x + t h z) / dt`` at ``t = 0``: ``(A z)^T b``."""
        v, c = self._image(z)
        return float(v @ c)

    def scaled_norm(self, z) -> float:
        """``||A z||``."""
        v = self._image(z)[0]
        return math.sqrt(float(v @ v))

    def variance_scaled(self):
        """``diag((A^T A)^+)`` (to be multiplied by ``h^2`` and the sigma factor)."""
        if self.svd is not None:
            Vt, _ = self.svd
            sv = self.sv
            inv = np.divide(1.0, sv * sv, out=np.zeros_like(sv), where=sv > sv[0] * 1e-15)
            return (Vt * Vt).T @ inv
        if self.vs is None:
            Rinv = self.Rinv
            if Rinv is None:
                Rinv = self.Rinv = trtri(self.R)[0]
            self.vs = row_norms2(Rinv)
        return self.vs


def row_norms2(Rinv):
    """Squared row norms of ``R^-1``: the scaled variance (eq. 52)."""
    return np.einsum("ij,ij->i", Rinv, Rinv)

def clearly_identifiable(F: Scaled, rank_tol: float, norms, floor: float):
    """The distances :func:`calibration.identifiability.classify` finds for
    the columns of ``F``'s matrix, where it would find every one identifiable
    by a margin that the round-off of a different QR of the same columns
    cannot cross; else None (classify then decides). ``norms``, ``floor``: its
    weighted column norms ``||G W_R[:, j]||`` and its zero floor, as it makes
    them. ``F`` factors ``A = G' W_R H`` with ``G'`` a constant times the check's
    ``G``, so ``||R[:, j]|| = ||A[:, j]||`` and ``|R[j, j]| / ||R[:, j]||`` is the
    distance of the unit column j from the span of the earlier ones (classify's
    ``r_diag``)."""
    R = F.R
    d = np.abs(R.diagonal()) / np.sqrt(np.einsum("ij,ij->j", R, R))
    # |R[j, j]| of unit columns is exact to a few n eps (backward stable QR);
    # the smallest of each (as Python lists: a few columns), and None where any
    # is NaN (Python's min can skip a NaN, their sum cannot)
    dmin = (d - 1e-12).tolist()
    nl = norms.tolist()
    total = sum(dmin) + sum(nl)
    if (total == total and min(dmin) > rank_tol
            and min([a * b for a, b in zip(dmin, nl)]) > floor * (1 + 1e-9) and min(nl) > floor):
        # and together too: the smallest singular value of the unit columns is at
        # least 1 / ||R_unit^-1||_F (classify's joint check where it is not clearly so)
        Rinv = F.Rinv
        if Rinv is not None:
            cn2 = np.einsum("ij,ij->j", R, R)
            if float(cn2 @ row_norms2(Rinv)) * rank_tol * rank_tol < 1.0:
                return d
    return None

