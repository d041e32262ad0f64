"""One iteration of Algorithm 2: the scaled, weighted problem, the damped step
and the adaptive damping (eqs. 47-49, 52 per iteration).

:class:`Scaled` factors ``[G W_R H, G r]`` once per iteration (one Householder
QR) and gives the damped step for every lambda tried there, the variance and
the condition number. :class:`Stepping` is the iteration loop of
:class:`calibration.solver.rounds.Algorithm2` (a mixin: it works on that
run's state, see there).
"""
from __future__ import annotations

import math

import numpy as np
from scipy.linalg import lapack

from calibration import rowblocks
from calibration.errors import CalibrationError

# Early switch to per-channel weights (see :func:`calibration.solver.rounds.solve`). The pooled round of a
# multi-channel problem stops before its step once the residual it predicts at
# its solution is reliable: the linearization's error, estimated from the last
# step's (which shrinks with the square of the step), is at most this fraction
# of every channel's predicted residual norm. The channel sigmas estimated from
# that prediction then differ from those at the pooled optimum by no more than
# this fraction (in practice far less), well inside the 5 % that decides
# whether a per-channel round is needed at all.
EARLY_SWITCH = 1e-2
#: an accepted step whose gain ratio (actual over predicted decrease) is above
#: this lowers the floor the damping is held at, the damping last rejected,
#: threefold (:meth:`Stepping.iterate`)
GOOD_GAIN = 0.75
#: after rejected steps, a Gauss-Newton step still predicting a decrease of the
#: cost of more than this (chi-square units, i.e. a step of ~0.1 std) is not convergence
STALL_CHI2 = 1e-2
#: a rejected step is retried no longer than this fraction of it (10 % more at
#: most: :meth:`Scaled.damping_for`), nor shorter than ``RETRY_SHORTEST`` of it
#: (within those, where the cost along the step is least on the parabola through
#: the two costs and the slope; MINPACK's lmder)
RETRY_LONGEST, RETRY_SHORTEST = 0.5, 0.1
#: a step is taken without evaluating the model after it (the iteration ends
#: there, :meth:`Stepping.iterate`) where the steps shrink at least this fast
#: (each at most this fraction of the one before) and the step after it is
#: predicted below epsilon
SETTLED_CONTRACTION = 0.1
#: the largest step (parameter units) whose linearization error is kept for that
#: bound
LINEARIZATION_WATCH = 1e-2
#: the residual (2-norm, SI units) below which a fit is exact (noise-free): the
#: convergence is then quadratic and the step after a step is bounded from that
#: step's linearization error (:meth:`Scaled.next_step_bound`); the
#: exact-fit limit of :mod:`calibration.solver.weighting`
EXACT_RESIDUAL = 1e-10
#: that bound must be below this fraction of epsilon: the error read off the last
#: step scales with the square of the step but changes direction (up to sixfold
#: under on sm-distance-tilt noise-free, 17 poses, seed 5)
EXACT_MARGIN = 0.1

#: a damping ``lambda^2`` at most this fraction of the smallest singular value's
#: square changes the step only at round-off (:meth:`Scaled.step` then solves the
#: undamped triangle: one LAPACK call instead of a second QR)
ROUNDOFF_DAMPING = 2.0 ** -53

#: an observation matrix larger than this (bytes) is let go before the model is
#: evaluated at a trial point, and evaluated again at the current one where the step is
#: rejected (:meth:`Stepping.iterate`): one matrix of the fit's size alive, not two
#: (a 100 000-pose motion capture's is 460 MB)
RELEASE_BYTES = 64 << 20

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

    def damping_for(self, length: float, lam2: float) -> float:
        """The ``lambda^2``, not below ``lam2``, whose damped step is at most 10 %
        longer than ``length`` (scaled) and, if ``lam2``'s is longer, no shorter:
        Newton's method on ``1/||z(lambda^2)||``, increasing and concave in
        ``lambda^2``, from ``lam2`` (below the root: it converges from there
        without overshooting; Moré 1978, as MINPACK's lmpar). From the SVD of
        ``R`` (``A``'s singular values, ``c`` in their basis), n x n."""
        if self.svd is None:
            U, sv, _ = np.linalg.svd(self.R)
            c = U.T @ self.Rc[:, self.n]
        else:
            sv, c = self.sv, self.svd[1]
        s0 = float(sv[0])
        if not s0 > 0:
            return lam2
        keep = sv > s0 * 1e-15  # (the pseudo-inverse's cut, as :meth:`step`)
        s2 = sv[keep] * sv[keep]
        sc2 = s2 * (c[keep] * c[keep])
        mu = lam2
        for _ in range(30):
            q = s2 + mu
            n2 = float(np.sum(sc2 / (q * q)))
            nz = math.sqrt(n2)
            if not nz > 1.1 * length:
                break
            # d(1/||z||)/d mu = (sum sc2 / q^3) / ||z||^3
            dphi = float(np.sum(sc2 / (q * q * q))) / (n2 * nz)
            if not dphi > 0:
                break
            mu += (1.0 / length - 1.0 / nz) / dphi
        return mu

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

    def retry_damping(self, z, lam2: float, cost: float, cost_try: float) -> float:
        """The ``lambda^2`` at which to retry the rejected step ``z`` (made at
        ``lam2``; the cost ``cost`` here, ``cost_try`` there): its step between
        :data:`RETRY_SHORTEST` and :data:`RETRY_LONGEST` as long as ``z`` (within
        10 % above: :meth:`damping_for`), where the parabola through the two costs
        and the slope here has its minimum along ``z`` (MINPACK's rule for its
        trust radius)."""
        slope = self.slope(z)
        rise = cost_try - cost + slope  # > slope: the cost rose, or fell less than predicted
        t = 0.5 * slope / rise if slope > 0 and rise > 0 else RETRY_SHORTEST
        t = min(max(t, RETRY_SHORTEST), RETRY_LONGEST)
        return self.damping_for(t * math.sqrt(float(z @ z)), lam2)

    def scaled_norm(self, z) -> float:
        """``||A z||``."""
        v = self._image(z)[0]
        return math.sqrt(float(v @ v))

    def next_step_bound(self, err) -> float:
        """In a fit with no residual left after a step whose linearization error
        has the (weighted, ``g e``) norm ``err``: a bound on the largest parameter
        change of the Gauss-Newton step from there, ``h R^-1 Q^T g e``: component
        ``i`` at most ``h_i ||row i of R^-1|| ||g e||``. Infinite without ``R^-1``."""
        Rinv = self.Rinv
        if Rinv is None:
            return math.inf
        return math.sqrt(float(np.max(self.h * self.h * row_norms2(Rinv)))) * err

    def held_back(self, z, lam2: float) -> float:
        """The largest parameter change of the part of the Gauss-Newton step that
        the damping ``lam2`` held back from the step ``z`` (it comes back in the
        next step); 0 where the damping is below round-off (:meth:`step`)."""
        if not lam2 * self.rinv2 > ROUNDOFF_DAMPING:
            return 0.0
        return float(np.max(np.abs(self.h * (self.step(0.0) - z))))

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



class Stepping:
    """The iteration of Algorithm 2 (mixin of :class:`calibration.solver.rounds.Algorithm2`)."""

    def evaluate(self, x):
        self.nfev += 1
        return self.model.evaluate(x)
    def _factor(self):
        """The iteration's scaled, weighted problem (:class:`Scaled`), or the
        mask of active columns that vanished."""
        W = self.W
        cols = None if self.all_active else self.active_idx
        norms = rowblocks.column_norms(W, cols)
        nl = norms.tolist()  # (a few columns: Python's max and min are faster than numpy's)
        tol = self.opt.rank_tol * max(nl)
        total = sum(nl)
        if min(nl) <= tol and total == total:  # (a NaN norm: on to the QR, as numpy's NaN max did)
            return norms <= tol
        h = 1.0 / norms if self.opt.scale_columns else np.ones(len(norms))
        return Scaled(self.W_key, self.sigma, W, h, self.g, self.r, cols)

    def _records_stated(self) -> bool:
        """Does :meth:`_record` record this round's iterations at the stated sigma with
        weights other than the round's (:meth:`_stated_factor`)?"""
        return (self.mode == "pooled" and self.all_known and bool(self.opt.weight_errors)
                and not self.stated_uniform())

    def _stated_factor(self, F):
        """``F``'s point factored at the stated weights (made once, while the run's
        matrix is still ``F``'s)."""
        if F.stated is None:
            F.stated = Scaled(F.key, self.known, self.W, F.h, self.sqrt_weights(self.known),
                              F.r, None if self.all_active else self.active_idx)
        return F.stated

    def _let_go(self) -> bool:
        """Let the observation matrix go before the model is evaluated at another point
        where it is large (:data:`RELEASE_BYTES`); True if it was."""
        if self.W.nbytes <= RELEASE_BYTES:
            return False
        self.W = None
        return True

    def _record(self, F, step, cost):
        """History entry: variance of the estimate at this iteration (eq. 52,
        from the factored scaled, weighted matrix) and its condition number."""
        idx = None if self.all_active else self.active_idx
        # the pooled round of a fit whose every sigma is stated records at the stated
        # sigma (the noise its variance and cost are stated at), as its later rounds do
        stated = self.mode == "pooled" and self.all_known and self.opt.weight_errors
        if stated and not self.stated_uniform():
            # weights other than the round's (the restart's path): the same iteration
            # factored at the stated weights
            F = self._stated_factor(F)
            factor, cost = 1.0, F.cost
        elif self.mode == "pooled" or not self.opt.weight_errors:
            g = F.g
            g0 = g if isinstance(g, float) else g[0]
            factor = float(g0 * g0 * (self.known if stated else self.sigma)[self.ch0] ** 2)
            if stated:  # 0.5 r^T r g0^2 -> 0.5 r^T r / sigma^2
                cost = cost / factor
        else:
            factor = 1.0
        # the scaled variance, or the R^-1 whose squared row norms it is (formed when read)
        v = F.Rinv if F.vs is None and F.Rinv is not None else F.variance_scaled()
        var = (factor, F.h, v, idx, len(self.active))
        it = Iteration(self.x.copy(), var, F.cond_or_triangle, step, cost,
                       dict(self.known if stated else self.sigma))
        self.history.append(it)
        if self.callback is not None:
            self.callback(self.k, it)

    def _reweighed(self, rss=None):
        """The weights at the current residual: in the pooled round its sigma (eq.
        51, one for all rows; ``rss``: ``r^T r`` where already made)."""
        if self.mode == "pooled":
            r = self.r
            self.sigma = self._pooled_sigma(float(r @ r) if rss is None else rss, self.rows,
                                            self.n_active)
        self._set_weights()

    def _stalled(self, F) -> bool:
        """After rejected steps, whether the undamped (Gauss-Newton) step at this
        point still predicts a cost decrease of more than :data:`STALL_CHI2` in
        units of the residual variance. At a minimum (any stationary point) the
        gradient vanishes and so does that decrease, whatever the damping; a step
        made small only by the damping (the edge of a model's domain, a PM that
        cannot assemble beyond it) is not convergence."""
        dof = F.rows - F.n
        if dof <= 0 or F.cost <= 0:
            return False
        z0 = F.step(self.lam ** 2)
        decrease = 0.5 * F.scaled_norm(z0) ** 2
        return decrease > STALL_CHI2 * F.cost / dof

    def _relaxed(self, F, z, cost, cost_try, floor) -> tuple[float, float]:
        """The damping after an accepted step ``z`` once the damping swings
        (see :meth:`iterate`), by its gain ratio ``rho`` (actual over predicted
        decrease of the cost; Nielsen 1999, Madsen, Nielsen & Tingleff 2004):
        ``lambda^2`` times ``max(1/3, 1 - (2 rho - 1)^3)``, never below lambda
        nor ``floor`` (the damping last rejected). A step the linear model
        predicted well relaxes the damping, a poor one (rho near 0) raises it.
        Returns ``(damping, rho)``."""
        p_dec = F.predicted(z)
        if p_dec > 1e-10 * cost:
            rho = min(max((cost - cost_try) / p_dec, 0.0), 1.0)
            f2 = max(1.0 / 3.0, 1.0 - (2.0 * rho - 1.0) ** 3)
        else:  # a decrease at round-off: the linear model is as good as exact
            f2, rho = 1.0 / 3.0, 1.0
        return max(self.lam, floor, self.lam_eff * math.sqrt(f2)), rho

    @staticmethod
    def _settles(step: float, taken, eps: float, held: float = 0.0) -> bool:
        """Is the step after ``step`` predicted below ``eps``? ``taken``: the
        steps accepted in a row before it (largest parameter change each). The
        last two each contracted the one before by at least
        :data:`SETTLED_CONTRACTION`, ``step`` is below ``sqrt(eps)``, and the
        next step extrapolated at the last rate, ``step * c`` with ``c = step /
        taken[-1]``, plus ``held``, the part of the Gauss-Newton step the damping
        held back (where the damping is near a weak singular value, that part
        shrinks slowly while the step's largest component falls fast), is below
        ``eps``. That rate, not a quadratic model: the
        quadratic constant read off the last two steps (largest components, in
        changing directions) was off a hundredfold (sm-distance noise-free, 30
        poses, seed 38), and a fit with a residual converges at a steady rate."""
        if len(taken) < 2 or step * step > eps:
            return False
        last, before = taken[-1], taken[-2]
        if not (last > 0 and before > 0):
            return False
        c = step / last
        if c > SETTLED_CONTRACTION or last > SETTLED_CONTRACTION * before:
            return False
        return step * c + held < eps

    def iterate(self, early: bool = False) -> tuple[bool, str]:
        """Iterate on the current active set until the step is below epsilon, or
        until a step after which the next is predicted below it (taken without
        evaluating the model there: :meth:`_settles`, :meth:`Scaled.next_step_bound`;
        ``self.settled`` then set, and the next round evaluates it first).

        ``early`` (pooled mode only): also stop before a step, with
        ``self.stopped_early`` and ``self.r_pred`` set and nothing recorded,
        once the residual that step's linearization predicts is reliable
        (``EARLY_SWITCH``)."""
        opt = self.opt
        eps, adaptive, max_iter = opt.epsilon, opt.adaptive, opt.max_iter
        rejected = 0
        # Adaptive damping (Levenberg-Marquardt safeguard): a rejected step is retried
        # with at least ten times the damping and at a damping whose step is at most
        # about half as long (0.55), as far along it as the parabola through the two
        # costs and the slope puts the least cost (no shorter than a tenth: MINPACK's
        # trust-radius rule; :meth:`Scaled.retry_damping`). Ten times alone lowered
        # the cost of a first rejected Gauss-Newton step by 13 % where lm's retry (and
        # now ours, at the same point) lowers it tenfold, and then swung into a curved
        # valley (AGEBOT's arm as a robot file from its nominal, sigma stated: 49
        # iterations and 56 evaluations against lm's 11; 8 and 9 now). An accepted
        # step relaxes the damping tenfold (never below lambda). Where that swings,
        # i.e. two iterations in a row needed a rejected step first, the damping
        # tenfold down is rejected again and again (a curved valley: sm-distance at
        # 100 poses took 106 iterations and 210 evaluations): from then on, in this
        # round, an accepted step relaxes the damping by its gain ratio
        # (:meth:`_relaxed`), no lower than the damping last rejected, a floor that
        # each step the linear model predicted well (gain ratio above GOOD_GAIN)
        # lowers threefold: held for the rest of the round it kept the damping far
        # above the weak directions' singular values where the rejection happened far
        # from the solution (the same robot file: floor 666 against s_min 50-150, 440
        # iterations); ``SolverOptions.hold_damping`` keeps it, as the PM start fit
        # needs: calibration.pm_start. The retry is never less damped than ten times:
        # a smaller rise keeps the steps towards the spurious minimum a Gauss-Newton
        # step can point at (sm-distance), and retrying at a fixed fraction of the
        # length alone (a trust region, where the damping is far above the weak
        # singular values a milder rise than tenfold) left the 6-9-pose planning
        # refits of far-off arms unconverged more often (a session's scout refit went
        # from 2e-9 to 7e-2 of residual and the far-off arm's session failed its gate;
        # docs/methods.md).
        swings = 0  # consecutive iterations that began with a rejected step
        cautious = False
        lam_rej = 0.0  # the damping last rejected
        resumed = self.stopped_early and self.next_factor is not None
        self.lam_eff = self.lam
        self.stopped_early = False
        self.r_pred = None
        self.last_factor = None
        early = early and self.mode == "pooled"
        pred = None  # (predicted residual after the last step, its ||z||, ||actual - predicted||)
        F = None  # the factored problem at the current x and weights
        # the steps (max |d|) accepted in a row since the last rejection (carried
        # on where the pooled round resumes after its early stop)
        taken = self.taken if resumed else []
        self.taken = taken
        lin_err = self.lin_err if resumed else None  # (r - r_lin, ||z||^2) of the last step
        if self.settled:  # the last round ended on a step not evaluated: evaluate it now
            self.settled = False
            released = self._let_go()
            try:
                self.r, self.W = self.evaluate(self.x)
                self.W_key, self.W_at = object(), self.x
            except CalibrationError as e:
                if released:  # (the matrix of the point before, as it was)
                    self.W = self.model.evaluate(self.W_at)[1]
                return False, f"the model cannot be evaluated at the solution ({e})"
            self.next_factor = None
            self._reweighed()
        while self.k < max_iter:
            if F is None:
                F, self.next_factor = self.next_factor, None
            if F is None:
                try:
                    F = self._factor()
                except np.linalg.LinAlgError:
                    return False, f"the observation matrix is not finite at iteration {self.k + 1}"
                if not isinstance(F, Scaled):
                    # a column that vanishes as the model fits the data (e.g. q2_off
                    # of sm-self-redundancy): not identifiable after all
                    mask = np.zeros_like(self.active)
                    mask[np.flatnonzero(self.active)[F]] = True
                    self.drop(mask)
                    F = pred = lin_err = None
                    taken.clear()
                    continue
            # one factorization gives the damped step for any lambda (eq. 48),
            # the condition number and the variance (eq. 52)
            lam2 = self.lam_eff ** 2
            z = F.step(lam2)
            d = F.h * z
            dl = d.tolist()  # (a few parameters: Python's max is faster than numpy's)
            step = max(map(abs, dl))
            total = sum(dl)
            if not math.isfinite(step) or total != total:  # (max can skip a NaN, the sum not)
                return False, f"the step became non-finite at iteration {self.k + 1}"
            cost = F.cost
            if step < eps:  # converged: the step is below the tolerance
                if rejected and self._stalled(F):
                    return False, (f"stalled at iteration {self.k + 1}: the damping, not the "
                                   "data, made the step small (the Gauss-Newton step still "
                                   "lowers the cost by a significant amount, but every step "
                                   "tried raises it or leaves the model's domain): not a "
                                   "minimum")
                self.k += 1
                self._record(F, step, cost)
                self.last_factor = F
                return True, ""
            watch = not rejected and step <= LINEARIZATION_WATCH
            # may this step be the last (below sqrt(epsilon), not after a rejection)?
            last = self.can_settle and not rejected and step * step <= eps and bool(taken)
            r_lin = None  # the residual this step predicts (where needed)
            if early or watch or last:
                r_lin = self.r - rowblocks.matvec(self.W, d, None if self.all_active
                                                  else self.active_idx)
            if early:
                zn = math.sqrt(z @ z)
                if pred is not None and pred[1] > 0:
                    # error of the predicted residual: the linearization's (that of
                    # the last step, scaled by the square of the steps) and the
                    # damping's (the part of the undamped step it holds back,
                    # at most lambda^2 / s_min^2 of the predicted change),
                    # against each channel's predicted residual
                    err = pred[2] * (zn / pred[1]) ** 2
                    rss_ch = np.bincount(self.row_channel, weights=r_lin * r_lin,
                                         minlength=len(self.channels))
                    limit = EARLY_SWITCH * math.sqrt(float(rss_ch.min()))
                    # the damping's part only where the linearization's leaves room
                    # (it needs s_min, the singular values of R)
                    if lam2 > 0 and err <= limit:
                        err += lam2 / F.smin ** 2 * F.scaled_norm(z)
                    if err <= limit:
                        self.stopped_early, self.r_pred = True, r_lin
                        self.lin_err = lin_err
                        self.next_factor = F  # the resumed round starts here (same weights)
                        return True, ""
            # (after the early stop: where both would end the pooled round there, the
            # early stop's resumed round needs no evaluation at a new point)
            settle = False
            if last:
                held = F.held_back(z, lam2)
                settle = self._settles(step, taken, eps, held)
                if (not settle and lin_err is not None
                        and float(r_lin @ r_lin) <= EXACT_RESIDUAL ** 2):
                    # an exact fit: the linearization error after this step, from
                    # the last step's (second order: as the square of the scaled
                    # steps), bounds the step after it
                    e_prev, zn2_prev = lin_err
                    ge = F.g * e_prev
                    err = math.sqrt(float(ge @ ge)) * float(z @ z) / zn2_prev
                    settle = F.next_step_bound(err) + held < EXACT_MARGIN * eps
            if settle:
                # the step after this one is predicted below epsilon: take this one
                # without evaluating the model there (the residual as the step's
                # linearization predicts it, off by O(step^2); the observation
                # matrix and the factorization of this point, off by O(step))
                if self.all_active:
                    self.x = self.x + d
                else:
                    self.x = self.x.copy()
                    self.x[self.active_idx] += d
                self.r = r_lin
                self.settled = True
                self.k += 1
                self._reweighed()
                self._record(F, step, cost)
                self.last_factor = F
                return True, ""
            if self.all_active:
                x_try = self.x + d
            else:
                x_try = self.x.copy()
                x_try[self.active_idx] += d
            if self._records_stated():  # (its record needs this point's matrix)
                self._stated_factor(F)
            released = self._let_go()
            try:
                r_try, W_try = self.evaluate(x_try)
                g = F.g
                if isinstance(g, float):  # one weight for all rows
                    rss = float(r_try @ r_try)
                    cost_try = 0.5 * (g * g) * rss
                else:
                    rg = r_try * g
                    cost_try = 0.5 * float(rg @ rg)
                ok = (math.isfinite(cost_try + float(W_try.sum()))
                      or bool(np.all(np.isfinite(r_try)) and np.all(np.isfinite(W_try))))
            except CalibrationError:  # e.g. the PM cannot assemble there
                ok, r_try, W_try = False, None, None
            if not ok or cost_try > cost * (1 + 1e-12):
                if released and (adaptive or not ok):  # rejected: the matrix here again
                    W_try = None
                    self.W = self.model.evaluate(self.W_at)[1]
                if adaptive:
                    rejected += 1
                    if rejected > 30:
                        return False, f"no step lowers the cost any more (iteration {self.k + 1})"
                    lam_rej = self.lam_eff
                    lam_new = max(10 * self.lam_eff, 1e-3 * F.s0)
                    if ok:  # and at least as short as the parabola along it says
                        lam_new = max(lam_new, math.sqrt(F.retry_damping(z, lam2, cost,
                                                                         cost_try)))
                    self.lam_eff = lam_new
                    taken.clear()
                    continue
                if not ok:
                    return False, f"the step left the model's domain at iteration {self.k + 1}"
            if adaptive:
                swings = swings + 1 if rejected else 0
                cautious = cautious or swings >= 2
                if cautious:
                    self.lam_eff, rho = self._relaxed(F, z, cost, cost_try, lam_rej)
                    if rho > GOOD_GAIN and not opt.hold_damping:
                        lam_rej /= 3.0  # the rejection was elsewhere: the floor gives way
                else:
                    self.lam_eff = max(self.lam, self.lam_eff / 10)
            if rejected:
                taken.clear()
            else:
                taken.append(step)
            # this step's linearization error (an exact fit's next step is bounded by it)
            lin_err = (r_try - r_lin, float(z @ z)) if watch else None
            rejected = 0
            if early:
                e = r_try - r_lin
                pred = (r_lin, zn, math.sqrt(e @ e))
            self.x, self.r, self.W = x_try, r_try, W_try
            self.W_key, self.W_at = object(), x_try
            W_try = None  # (the run's own now: no other reference, _let_go)
            self.k += 1
            self._reweighed(rss if isinstance(F.g, float) else None)
            self._record(F, step, cost)
            F = None
        return False, f"no convergence within {opt.max_iter} iterations"
