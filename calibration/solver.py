"""Algorithm 2 of the report (section 5): linearized iterative least squares
with identifiability, column scaling H, error weighting L and damping.

One solver for every measurement model (:class:`calibration.model.MeasurementModel`).
Each iteration k, on the identifiable parameters ``xi_R``:

1. ``r, W = model.evaluate(xi)``; ``W_R`` the identifiable columns;
2. scaling ``H = diag(1/||W_R[:, i]||)`` (eq. 47);
3. weighting ``L = Sigma_v^-1`` per channel: the trace's sigma if known, else
   the estimate of the previous iteration (eq. 51 per channel; ``L = I`` in the
   first iteration);
4. damped step ``d = (W~^T L W~ + lambda^2 I)^-1 W~^T L r`` (eq. 48), solved
   as a least-squares problem (QR), then ``d_R = H d`` (eq. 49);
5. ``sigma^2`` (eq. 51) and covariance ``(W_R^T Sigma^-1 W_R)^-1`` (eq. 52);
6. stop when ``max |d_R| < epsilon``, or at the iteration limit.

Identifiability is analysed at the start (structural dependencies) and again
at the solution (:mod:`calibration.identifiability`): parameters found
non-identifiable there return to their start values and the iteration resumes
without them. Convergence is reported in the result, never raised.

Cost: one Householder QR of ``[G W_R H, G r]`` per iteration gives the step
for every damping tried there, the variance and (with the singular values of
its small triangle) the condition number; the final covariance and condition
number reuse a QR already made at the solution where the weights allow. The
per-channel weights of a multi-channel fit are fixed as soon as the pooled fit
predicts its solution's residual reliably (see :func:`solve`), not after
iterating the pooled fit to epsilon.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np
from scipy.linalg import lapack

from calibration import identifiability as ident
from calibration.errors import CalibrationError
from calibration.model import MeasurementModel

# Below this (in the residual's SI units) a sigma estimate is round-off, not noise.
SIGMA_FLOOR = 1e-14


@dataclass(frozen=True)
class SolverOptions:
    """Settings of Algorithm 2.

    damping:        lambda of eq. 39/48 (None: the method's default).
    epsilon:        stop when ``max |d xi_R| < epsilon`` (parameter units).
    max_iter:       iteration limit (over all identifiability rounds).
    scale_columns:  H (eq. 47); False reproduces the report's "H = I" run.
    weight_errors:  L (eq. 48); False keeps ``L = I`` throughout.
    sigma:          channel -> known standard deviation of one residual row of
                    that channel (residual units); None: estimated (eq. 51).
    rank_tol, kappa: identifiability thresholds (calibration.identifiability).
    recheck:        re-analyse identifiability at the solution.
    fixed:          parameter names kept at their start values.
    adaptive:       reject a step that raises the weighted cost and retry it with
                    ten times the damping (Levenberg-Marquardt safeguard); the
                    damping relaxes back to lambda after accepted steps. False
                    runs the report's plain Algorithm 2.
    """

    damping: float | None = None
    epsilon: float = 1e-10
    max_iter: int = 1000
    scale_columns: bool = True
    weight_errors: bool = True
    sigma: dict | None = None
    rank_tol: float = 1e-8
    kappa: float = 3.0
    recheck: bool = True
    fixed: tuple[str, ...] = ()
    adaptive: bool = True


@dataclass(frozen=True)
class Iteration:
    """One iteration's record (the data behind the report's figures)."""

    x: np.ndarray  # (N,) parameters after the step
    variance: np.ndarray  # (N,) variance of each parameter (NaN where not calibrated)
    condition_number: float  # of the scaled, weighted observation matrix
    step: float  # max |d xi_R|
    cost: float  # 0.5 * r^T L r before the step
    sigma: dict  # channel -> sigma estimate


@dataclass(frozen=True)
class CalibrationResult:
    """Everything a caller needs (after scipy's OptimizeResult).

    x, std:        ``(N,)`` calibrated values and standard deviations (NaN std
                   for parameters that were not calibrated).
    covariance:    ``(N_R, N_R)`` over ``covariance_names``.
    status:        per parameter :class:`calibration.identifiability.ParameterStatus`.
    converged, message, iterations, nfev: how it ended.
    sigma:         channel -> estimated sigma of one row (eq. 51), residual units.
    residual_rms:  channel -> RMS of the final residual.
    condition_number: of the final scaled, weighted observation matrix.
    history:       list of :class:`Iteration`.
    """

    method: str
    names: tuple[str, ...]
    x: np.ndarray
    x0: np.ndarray
    std: np.ndarray
    covariance: np.ndarray
    covariance_names: tuple[str, ...]
    status: tuple[ident.ParameterStatus, ...]
    converged: bool
    message: str
    iterations: int
    nfev: int
    sigma: dict
    sigma_known: bool
    residual_rms: dict
    residual: np.ndarray
    condition_number: float
    cost: float
    history: tuple[Iteration, ...] = field(repr=False)
    n_rows: int = 0
    wall_time: float = 0.0

    @property
    def n_identifiable(self) -> int:
        return sum(s.identifiable for s in self.status)

    def value(self, name: str) -> float:
        return float(self.x[self.names.index(name)])

    def error_of(self, name: str) -> float:
        return float(self.std[self.names.index(name)])


# Early switch to per-channel weights (see solve). The pooled round of a
# multi-channel problem stops before its step once the residual it predicts at
# its solution is reliable: the linearization's error, estimated from the last
# step's (which shrinks with the square of the step), is at most this fraction
# of every channel's predicted residual norm. The channel sigmas estimated from
# that prediction then differ from those at the pooled optimum by no more than
# this fraction (in practice far less), well inside the 5 % that decides
# whether a per-channel round is needed at all.
EARLY_SWITCH = 1e-2
# A material change of a channel's sigma between rounds (relative).
SIGMA_CHANGE = 0.05

_geqrf, _gesvd, _trtrs, _trtri = lapack.dgeqrf, lapack.dgesvd, lapack.dtrtrs, lapack.dtrtri
_MASKS: dict[int, tuple] = {}


def _masks(n: int):
    """Per column count ``n`` (cached, Fortran order): the 0/1 mask of the upper
    triangle of an ``(n, n + 1)`` block (its last column, ``Q^T b``, kept whole)
    and the ``(2n, n + 1)`` array ``[0 0; I 0]`` that becomes ``[R c; lambda I 0]``."""
    m = _MASKS.get(n)
    if m is None:
        aug = np.zeros((2 * n, n + 1), order="F")
        aug[np.arange(n) + n, np.arange(n)] = 1.0
        m = _MASKS[n] = (np.asfortranarray(np.triu(np.ones((n, n + 1)))), aug)
    return m


class _Scaled:
    """One iteration's scaled, weighted least-squares problem ``A z ~ b`` with
    ``A = G W_R H`` (``g = diag(G)`` a float or per row) and ``b = G r``,
    factored once and reused for every damping tried at that point.

    Tall ``A`` (the normal case): one Householder QR of ``[A b]`` gives
    ``R`` and ``c = Q^T b``; the damped step (eq. 48) is the least-squares
    solution of ``[R; lambda I] z = [c; 0]`` (one small QR), the variance
    (eq. 52) the row norms of ``R^-1``, the condition number the singular values
    of ``R`` (those of ``A``). Where ``R`` is numerically singular, or ``A`` not
    tall, the same quantities come from an SVD with the singular values below
    ``1e-15 s_max`` cut (a pseudo-inverse), as the normal equations would."""

    __slots__ = ("R", "Rc", "Rinv", "W", "cost", "g", "h", "n", "s0", "sigma", "smin", "sv", "svd")

    def __init__(self, W, sigma, WA, h, g, r):
        rows, n = WA.shape
        self.W, self.sigma, self.h, self.g, self.n = W, sigma, h, g, n
        scalar = isinstance(g, float)
        self.svd = self.Rinv = None
        if rows <= n:
            A = WA * (h * g) if scalar else (WA * h) * g[:, None]
            b = r * g
            self.cost = 0.5 * float(b @ b)
            U, sv, Vt = np.linalg.svd(A, full_matrices=False)
            self.sv, self.svd = sv, (Vt, U.T @ b)
            self.s0, self.smin = float(sv[0]), float(sv[-1])
            self.Rc = self.R = None
            return
        Ab = np.empty((rows, n + 1), order="F")
        if scalar:
            np.multiply(WA, h * g, out=Ab[:, :n])
        else:
            np.multiply(WA, h, out=Ab[:, :n])
            Ab[:, :n] *= g[:, None]
        b = np.multiply(r, g, out=Ab[:, n])
        self.cost = 0.5 * float(b @ b)
        qr = _geqrf(Ab, overwrite_a=1)[0]
        # [R c] with R upper triangular and c = Q^T b (Fortran order: R contiguous)
        Rc = self.Rc = qr[:n] * _masks(n)[0]
        R = self.R = Rc[:, :n]
        sv, info = _gesvd(R, compute_uv=0)[1::2]
        svl = sv.tolist()
        s0 = self.s0 = svl[0]
        self.smin = svl[-1]
        if info != 0 or not math.isfinite(s0):
            raise np.linalg.LinAlgError("SVD did not converge")
        self.sv = sv
        if not self.smin > s0 * 1e-15:  # singular: pseudo-inverse through the SVD of R
            U, _sv, Vt = np.linalg.svd(R)
            self.svd = (Vt, U.T @ Rc[:, n])

    @property
    def cond(self) -> float:
        return self.s0 / self.smin if self.smin > 0 else math.inf

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
        if lam2 > 0:
            M = _masks(n)[1] * math.sqrt(lam2)
            M[:n] = self.Rc
            qr = _geqrf(M, overwrite_a=1)[0]
            return _trtrs(qr[:n, :n], qr[:n, n])[0]
        return _trtrs(self.R, self.Rc[:, n])[0]

    def scaled_norm(self, z) -> float:
        """``||A z||``."""
        v = self.R @ z if self.svd is None else self.sv * (self.svd[0] @ z)
        return math.sqrt(float(v @ v))

    def variance_scaled(self):
        """``diag((A^T A)^+)`` (to be multiplied by ``h^2`` and the sigma factor)."""
        if self.svd is not None:
            Vt, _ = self.svd
            sv = self.sv
            inv = np.divide(1.0, sv * sv, out=np.zeros_like(sv), where=sv > sv[0] * 1e-15)
            return (Vt * Vt).T @ inv
        Rinv = self.Rinv = _trtri(self.R)[0]
        return np.einsum("ij,ij->i", Rinv, Rinv)


class _Check:
    """An identifiability check at a solution (:meth:`_Algorithm2.recheck`):
    its inputs, its classification ``(identifiable, influences, r_diag,
    column_norm)`` and the triangle ``R`` of its QR (or None)."""

    __slots__ = ("R", "W", "candidates", "cls", "r", "sigma", "weights")

    def __init__(self, W, r, sigma, weights, candidates, cls, R):
        self.W, self.r, self.sigma, self.weights = W, r, sigma, weights
        self.candidates, self.cls, self.R = candidates, cls, R

    def saw(self, run, sigma) -> bool:
        """Did this check see the final solution of ``run``, weighted by ``sigma``
        (None: unweighted)?"""
        return (self.W is run.W and self.r is run.r
                and (self.sigma == sigma if sigma is not None and self.sigma is not None
                     else np.array_equal(self.weights, run.row_weights(sigma) if sigma else
                                         np.ones(run.rows))))


class _Algorithm2:
    """State of one run of Algorithm 2 (see module doc)."""

    def __init__(self, model: MeasurementModel, opt: SolverOptions, callback):
        self.model, self.opt, self.callback = model, opt, callback
        self.lam = model.default_damping if opt.damping is None else float(opt.damping)
        self.names = tuple(model.names)
        self.x0 = np.array(model.x0, dtype=float)
        self.x = self.x0.copy()
        known = dict(opt.sigma) if opt.sigma else {}
        self.channels = channels = tuple(model.channels)
        unknown = set(known) - set(channels)
        if unknown:
            raise CalibrationError(f"sigma given for unknown channel(s) {sorted(unknown)} "
                                   f"(method {model.method} has {list(channels)})")
        for ch, v in known.items():
            if not (np.isfinite(v) and v > 0):
                raise CalibrationError(f"sigma of channel {ch!r} must be a positive number, not {v!r}")
        self.known = known
        self.all_known = set(known) == set(channels)
        # weighting mode: 'known' (trace sigma), 'pooled' (eq. 51 during the
        # iteration), 'channel' (per-channel sigma fixed from the last solution)
        self.mode = "known" if self.all_known else "pooled"
        self.r, self.W = model.evaluate(self.x)
        self.nfev = 1
        self.rows = len(self.r)
        if not (math.isfinite(float(self.r.sum()) + float(self.W.sum()))
                or (np.all(np.isfinite(self.r)) and np.all(np.isfinite(self.W)))):
            raise CalibrationError("the model gives non-finite values at the start parameters")
        self.row_channel = np.asarray(model.row_channel, dtype=np.intp)
        self.channel_count = np.bincount(self.row_channel, minlength=len(channels))
        self.ch0 = channels[self.row_channel[0]] if self.rows else None
        self.sigma = (dict(known) if self.all_known else dict.fromkeys(channels, 1.0))
        self._g_sigma = None  # the sigma dict self.g was made from
        self._set_weights()
        fixed = opt.fixed
        self.candidates = (np.array([nm not in fixed for nm in self.names]) if fixed
                           else np.ones(len(self.names), bool))
        self.history: list[Iteration] = []
        self.k = 0
        self.lam_eff = self.lam
        self.cond = np.nan
        self.stopped_early = False
        self.r_pred = None  # residual predicted at the pooled solution (early stop)
        self.last_check = None  # the last recheck (_Check)
        self.last_factor = None  # the factorization the last iteration ended on
        self._sigma_memo = (None, -1, None)

    # -- sigma and weights -------------------------------------------------------
    def channel_sigma(self, r, n_active, pooled=False):
        """Sigma of one row per channel (eq. 51): known values where given; else
        estimated from the residual, pooled over all rows (the report's single
        sigma) or per channel with its share of the degrees of freedom."""
        n = len(r)
        if pooled:
            return self._pooled_sigma(float(r @ r), n, n_active)
        memo = self._sigma_memo
        if memo[0] is r and memo[1] == n_active:
            return dict(memo[2])
        rss = np.bincount(self.row_channel, weights=r * r, minlength=len(self.channels)).tolist()
        out = {}
        known = self.known
        for ch, nc, rc in zip(self.channels, self.channel_count.tolist(), rss):
            if ch in known:
                out[ch] = float(known[ch])
                continue
            dof = nc - n_active * nc / n
            out[ch] = max(math.sqrt(rc / dof) if dof > 0 else math.sqrt(rc / max(nc, 1)),
                          SIGMA_FLOOR)
        self._sigma_memo = (r, n_active, out)
        return dict(out)

    def _pooled_sigma(self, rss, n, n_active):
        dof = n - n_active
        s = math.sqrt(rss / dof) if dof > 0 else math.sqrt(rss / n)
        return dict.fromkeys(self.channels, max(s, SIGMA_FLOOR))

    def row_weights(self, sigma):
        """The diagonal of L = Sigma^-1 for ``sigma`` (channel -> sigma)."""
        s = np.array([sigma[ch] for ch in self.channels])[self.row_channel]
        return 1.0 / (s * s)

    def _set_weights(self):
        """``self.g = sqrt(L)``: a float where every row has the same weight
        (L = I, or the pooled sigma), else per row."""
        if not self.opt.weight_errors:
            self.g = 1.0
        elif self.mode == "pooled":
            self.g = 1.0 / float(self.sigma[self.channels[0]])
        elif self._g_sigma is not self.sigma:
            s = np.array([self.sigma[ch] for ch in self.channels], dtype=float)
            self.g = (1.0 / s)[self.row_channel]
            self._g_sigma = self.sigma

    def evaluate(self, x):
        self.nfev += 1
        return self.model.evaluate(x)

    # -- identifiability ------------------------------------------------------
    def initial_status(self):
        model, opt = self.model, self.opt
        twin = model.consistent_twin(self.x)
        if twin is model:
            g = self.g  # the first iteration's weights (L = I, or the trace's sigma)
            Wg = self.W * g if isinstance(g, float) else self.W * g[:, None]
            cls = ident.classify(Wg, candidates=self.candidates, rank_tol=opt.rank_tol)
        else:
            r_t, W_t = twin.evaluate(self.x)
            self.nfev += 1
            cls = ident.classify(W_t, candidates=self.candidates, residual=r_t,
                                 rank_tol=opt.rank_tol, kappa=opt.kappa)
        ok, dep = cls[0], cls[1]
        self._set_active(ok)
        if self.n_active == 0:
            raise CalibrationError("no parameter can be identified from these measurements")
        # parameters the measurements depend on at all; with too few rows the
        # rank is limited by the data, not by the method, and sigma (eq. 51)
        # needs at least one degree of freedom
        n_dep = int(np.count_nonzero(ok | dep))
        if self.rows <= n_dep:
            p = max(model.p, 1)
            raise CalibrationError(
                f"{model.n_poses} poses give {self.rows} equations for up to {n_dep} parameters; "
                f"at least {int(np.ceil((n_dep + 1) / p))} poses are needed "
                f"(recommended {ident.minimum_poses(n_dep, p)}, eq. 60)")

    def _set_active(self, mask):
        self.active = np.asarray(mask, bool)
        self.active_idx = np.flatnonzero(self.active)
        self.n_active = len(self.active_idx)
        self.all_active = self.n_active == len(self.active)
        self._nan = np.full(len(self.active), np.nan)

    @property
    def r_sol(self):
        """The residual at the solution: the current one, or after an early
        stop the one the last linearization predicts there."""
        return self.r if self.r_pred is None else self.r_pred

    def recheck(self) -> bool:
        """Identifiability at the solution; True if parameters were dropped."""
        opt = self.opt
        r = self.r_sol
        if opt.weight_errors:  # per-channel weights from the residual at the solution
            sigma = self.channel_sigma(r, self.n_active)
            weights = self.row_weights(sigma)
        else:
            sigma, weights = None, np.ones(self.rows)
        cand = self.active & self.candidates
        *cls, R = ident.classify(self.W, weights=weights, candidates=cand, residual=r,
                                 rank_tol=opt.rank_tol, kappa=opt.kappa, return_r=True)
        self.last_check = _Check(self.W, r, sigma, weights, cand, cls, R)
        new_active = cls[0] & self.active
        if np.array_equal(new_active, self.active):
            return False
        self.drop(self.active & ~new_active)
        return True

    def drop(self, mask):
        """Stop calibrating ``mask``; they return to their start values, or stay
        where they are if the model cannot be evaluated there."""
        self._set_active(self.active & ~mask)
        self.r_pred = None
        x = self.x.copy()
        x[mask] = self.x0[mask]
        try:
            self.r, self.W = self.evaluate(x)
            self.x = x
        except CalibrationError:
            self.r, self.W = self.evaluate(self.x)

    def _sigma_changed(self, sigma, old) -> bool:
        floor = all(v <= 10 * SIGMA_FLOOR for v in sigma.values())
        return not floor and any(abs(sigma[ch] / old[ch] - 1) > SIGMA_CHANGE for ch in sigma)

    def can_reweight(self) -> bool:
        return not (self.mode == "known" or not self.opt.weight_errors or len(self.channels) < 2)

    def channels_differ(self) -> bool:
        """Would :meth:`reweight` change the weights materially now?"""
        return self.can_reweight() and self._sigma_changed(
            self.channel_sigma(self.r_sol, self.n_active), self.sigma)

    def reweight(self) -> bool:
        """Per-channel weights at the solution; True if they changed materially."""
        if not self.can_reweight():
            return False
        sigma = self.channel_sigma(self.r_sol, self.n_active)
        old = self.sigma
        self.sigma, self.mode = sigma, "channel"
        self._set_weights()
        return self._sigma_changed(sigma, old)

    # -- iteration -------------------------------------------------------------
    def _factor(self):
        """The iteration's scaled, weighted problem (:class:`_Scaled`), or the
        mask of active columns that vanished."""
        W = self.W
        WA = W if self.all_active else W.take(self.active_idx, axis=1)
        norms = np.sqrt(np.einsum("ij,ij->j", WA, WA))
        tol = self.opt.rank_tol * norms.max()
        if norms.min() <= tol:
            return norms <= tol
        h = 1.0 / norms if self.opt.scale_columns else np.ones(len(norms))
        return _Scaled(W, self.sigma, WA, h, self.g, self.r)

    def _record(self, F, step, cost):
        """History entry: variance of the estimate at this iteration (eq. 52,
        from the factored scaled, weighted matrix) and its condition number."""
        self.cond = F.cond
        if self.mode == "pooled" or not self.opt.weight_errors:
            g = F.g
            g0 = g if isinstance(g, float) else g[0]
            factor = float(g0 * g0 * self.sigma[self.ch0] ** 2)
        else:
            factor = 1.0
        h = F.h
        var = (factor * (h * h)) * F.variance_scaled()
        if not self.all_active:
            var_all = self._nan.copy()
            var_all[self.active_idx] = var
            var = var_all
        it = Iteration(self.x.copy(), var, self.cond, step, cost, dict(self.sigma))
        self.history.append(it)
        if self.callback is not None:
            self.callback(self.k, it)

    def iterate(self, early: bool = False) -> tuple[bool, str]:
        """Iterate on the current active set until the step is below epsilon.

        ``early`` (pooled mode only): also stop before a step, with
        ``self.stopped_early`` and ``self.r_pred`` set and nothing recorded,
        once the residual that step's linearization predicts is reliable
        (``EARLY_SWITCH``)."""
        opt = self.opt
        eps, adaptive, max_iter = opt.epsilon, opt.adaptive, opt.max_iter
        rejected = 0
        self.lam_eff = self.lam
        self.stopped_early = False
        self.r_pred = None
        self.last_factor = None
        early = early and self.mode == "pooled"
        pred = None  # (predicted residual after the last step, its ||z||, ||actual - predicted||)
        F = None  # the factored problem at the current x and weights
        while self.k < max_iter:
            if F is None:
                try:
                    F = self._factor()
                except np.linalg.LinAlgError:
                    return False, f"the observation matrix is not finite at iteration {self.k + 1}"
                if not isinstance(F, _Scaled):
                    # a column that vanishes as the model fits the data (e.g. q2_off
                    # of sm-self-redundancy): not identifiable after all
                    mask = np.zeros_like(self.active)
                    mask[np.flatnonzero(self.active)[F]] = True
                    self.drop(mask)
                    F = pred = None
                    continue
            # one factorization gives the damped step for any lambda (eq. 48),
            # the condition number and the variance (eq. 52)
            lam2 = self.lam_eff ** 2
            z = F.step(lam2)
            d = F.h * z
            step = float(np.abs(d).max())
            if not math.isfinite(step):
                return False, f"the step became non-finite at iteration {self.k + 1}"
            cost = F.cost
            if step < eps:  # converged: the step is below the tolerance
                self.k += 1
                self._record(F, step, cost)
                self.last_factor = F
                return True, ""
            if early:
                WA = self.W if self.all_active else self.W.take(self.active_idx, axis=1)
                r_lin = self.r - WA @ d  # the residual this step predicts
                zn = math.sqrt(z @ z)
                if pred is not None and pred[1] > 0:
                    # error of the predicted residual: the linearization's (that of
                    # the last step, scaled by the square of the steps) and the
                    # damping's (the part of the undamped step it holds back,
                    # at most lambda^2 / s_min^2 of the predicted change),
                    # against each channel's predicted residual
                    err = pred[2] * (zn / pred[1]) ** 2
                    if lam2 > 0:
                        err += lam2 / F.smin ** 2 * F.scaled_norm(z)
                    rss_ch = np.bincount(self.row_channel, weights=r_lin * r_lin,
                                         minlength=len(self.channels))
                    if err <= EARLY_SWITCH * math.sqrt(float(rss_ch.min())):
                        self.stopped_early, self.r_pred = True, r_lin
                        return True, ""
            if self.all_active:
                x_try = self.x + d
            else:
                x_try = self.x.copy()
                x_try[self.active_idx] += d
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
                if adaptive:
                    rejected += 1
                    if rejected > 30:
                        return False, f"no step lowers the cost any more (iteration {self.k + 1})"
                    self.lam_eff = max(10 * self.lam_eff, 1e-3 * F.s0)
                    continue
                if not ok:
                    return False, f"the step left the model's domain at iteration {self.k + 1}"
            rejected = 0
            self.lam_eff = max(self.lam, self.lam_eff / 10)
            if early:
                e = r_try - r_lin
                pred = (r_lin, zn, math.sqrt(e @ e))
            self.x, self.r, self.W = x_try, r_try, W_try
            self.k += 1
            if self.mode == "pooled":  # eq. 51, one sigma for all rows
                self.sigma = self._pooled_sigma(rss, self.rows, self.n_active)
            self._record(F, step, cost)
            self._set_weights()
            F = None
        return False, f"no convergence within {opt.max_iter} iterations"


def solve(model: MeasurementModel, options: SolverOptions | None = None,
          callback=None) -> CalibrationResult:
    """Run Algorithm 2 on ``model``; ``callback(k, Iteration)`` after each iteration.

    Rounds: iterate to the solution; re-analyse identifiability there (drop
    what is not identifiable); estimate one sigma per channel and, if they
    differ materially from the weights used, iterate again with them. The
    first (pooled) round of a multi-channel problem with unknown sigma does
    not iterate to epsilon: it stops as soon as the residual at its solution
    is predicted reliably by the linearization (``EARLY_SWITCH``), and the
    identifiability check and the channel sigmas are judged on that
    prediction. Iterating the pooled round further would only refine a
    solution the per-channel round then moves by O(std) anyway. Where the
    channel sigmas turn out to agree, the pooled round simply resumes.
    """
    opt = options or SolverOptions()
    t_start = time.perf_counter()
    run = _Algorithm2(model, opt, callback)
    run.initial_status()
    converged, message = False, ""
    early = run.can_reweight() and run.mode == "pooled"
    rounds = 0
    while rounds < 6:
        converged, message = run.iterate(early=early and rounds < 5)
        if not converged:
            break
        if run.stopped_early and not run.channels_differ():
            early = False  # one sigma fits all channels: finish the pooled round
            continue
        rounds += 1
        changed = run.recheck() if opt.recheck else False
        changed = run.reweight() or changed
        if not changed:
            break
    # final statistics at the solution (eqs. 51, 52)
    names, active, rows, r = run.names, run.active, run.rows, run.r
    sigma = (dict(run.known) if run.all_known else run.channel_sigma(r, run.n_active))
    w_cov = run.row_weights(sigma)
    status = _final_status(run, sigma if opt.weight_errors else None,
                           w_cov if opt.weight_errors else np.ones(rows))
    cov, cond = _covariance(run, sigma, w_cov)
    std = np.full(len(names), np.nan)
    std[active] = np.sqrt(np.clip(np.diag(cov), 0, None))
    rss = np.bincount(run.row_channel, weights=r * r, minlength=len(run.channels)).tolist()
    rms = {ch: math.sqrt(s / nc) if nc else math.nan
           for ch, s, nc in zip(run.channels, rss, run.channel_count.tolist())}
    if converged:
        message = f"converged in {run.k} iterations (max step < {opt.epsilon:g})"
    return CalibrationResult(
        method=model.method, names=names, x=run.x, x0=run.x0, std=std, covariance=cov,
        covariance_names=tuple(nm for nm, a in zip(names, active) if a),
        status=tuple(status), converged=converged, message=message, iterations=run.k,
        nfev=run.nfev, sigma=sigma, sigma_known=run.all_known, residual_rms=rms,
        residual=r, condition_number=cond, cost=0.5 * float(r @ (w_cov * r)),
        history=tuple(run.history), n_rows=rows, wall_time=time.perf_counter() - t_start)


# (cond * column-norm spread)^2 below which the covariance is taken from the QR
# of the scaled matrix; above it, as the normal matrix nears 1/eps, the
# pseudo-inverse of the normal matrix (what eq. 52 reads) cuts singular values.
_PINV_SAFE = 1e13


def _covariance(run, sigma, w):
    """Covariance ``(W_R^T L W_R)^-1`` (eq. 52) and the condition number of the
    scaled, weighted ``G W_R H`` at the solution, ``L = diag(w)`` (``w`` from
    ``sigma``), from a QR already made there where possible: the last
    iteration's (weights proportional to ``w``: known sigma, one sigma for all
    rows) or the identifiability recheck's (same weights; its unit columns
    differ from ``G W_R H`` by a column scaling only); else a QR of ``G W_R H``.
    Either way ``H (R^T R)^-1 H``. Where the normal matrix is so
    ill-conditioned that a pseudo-inverse would cut singular values it is that
    pseudo-inverse, as eq. 52 reads."""
    scale = run.opt.scale_columns
    WA = run.W if run.all_active else run.W.take(run.active_idx, axis=1)
    rows, n = WA.shape
    F = run.last_factor
    if F is not None and F.W is run.W and F.svd is None and F.Rinv is not None:
        # weights of the last iteration: a constant times w?
        g = F.g
        if isinstance(g, float):
            vals = list(sigma.values())
            c = 1.0 / (vals[0] ** 2 * g * g) if all(v == vals[0] for v in vals) else None
        else:
            c = 1.0 if F.sigma == sigma else None  # known sigma, or unchanged by reweight
        if c:
            h = F.h
            spread = float(h.max() / h.min()) if scale else 1.0
            if (F.cond * spread) ** 2 < _PINV_SAFE:  # w = c g^2: G W_R H = sqrt(c) A
                Rh = F.Rinv * h[:, None]
                return (Rh @ Rh.T) * (1.0 / c), F.cond
    norms = np.sqrt(np.einsum("ij,ij->j", WA, WA))
    h = 1.0 / norms if scale else np.ones(n)
    if n and rows > n and norms.min() > 0:
        chk = run.last_check
        if (chk is not None and chk.R is not None and chk.saw(run, sigma)
                and np.array_equal(chk.cls[0], run.active)):
            # the recheck's R is that of G W_R D, D = 1/||G W_R[:, j]||: G W_R H = (G W_R D) S
            # with S = diag(||G W_R[:, j]|| h_j), so R S is the triangle of G W_R H
            R = chk.R * (chk.cls[3][run.active_idx] * h)
        else:
            qr, _tau, _work, info = _geqrf(np.asfortranarray(WA * h * np.sqrt(w)[:, None]))
            R = qr[:n, :n] * _masks(n)[0][:, :n] if info == 0 else None
        if R is not None:
            svl = _gesvd(R, compute_uv=0)[1].tolist()
            if all(math.isfinite(v) for v in svl) and svl[-1] > 0:
                cond = svl[0] / svl[-1]
                spread = float(norms.max() / norms.min()) if scale else 1.0
                if (cond * spread) ** 2 < _PINV_SAFE:
                    Rinv, info = _trtri(R)
                    if info == 0:
                        Rh = Rinv * h[:, None]
                        return Rh @ Rh.T, cond
    cov = np.linalg.pinv(WA.T @ (WA * w[:, None]))
    sv = np.linalg.svd((WA * h) * np.sqrt(w)[:, None], compute_uv=False)
    cond = float(sv[0] / sv[-1]) if sv.size and sv[-1] > 0 else np.inf
    return cov, cond


def _final_status(run, sigma, weights):
    """Classification reported to the operator: identifiable = calibrated; the
    others classified by their columns at the solution (zero column: no
    influence; dependent: influences the model).

    The recheck at this solution usually saw the same matrix, weights and
    residual; its classification is reused where the parameters it left out
    (not calibrated) have columns that count as zero here too, so that they
    could not have changed anything."""
    opt = run.opt
    cls = None
    chk = run.last_check
    if opt.recheck and chk is not None and chk.saw(run, sigma):
        ok, dep, rdiag, norms = chk.cls
        extra = run.candidates & ~chk.candidates
        if not extra.any():
            cls = chk.cls
        else:
            # a zero column is left out of the QR, and so changes nothing, if it
            # does not raise the largest candidate norm (the rank floor) either
            floor_rank = opt.rank_tol * float(norms.max(initial=0.0, where=chk.candidates))
            rg = np.sqrt(weights) * run.r
            floor = max(floor_rank, opt.kappa * math.sqrt(float(rg @ rg)))
            ne = norms[extra]
            if np.all(ne <= floor) and opt.rank_tol * float(ne.max()) <= floor_rank:
                cls = chk.cls
    if cls is None:
        cls = ident.classify(run.W, weights=weights, candidates=run.candidates,
                             residual=run.r if opt.recheck else None,
                             rank_tol=opt.rank_tol, kappa=opt.kappa)
    ok, dep, rdiag, norms = cls
    out = []
    for nm, a, i_ok, i_dep, rd, cn in zip(run.names, run.active.tolist(), ok.tolist(),
                                          dep.tolist(), rdiag.tolist(), norms.tolist()):
        if a:
            out.append(ident.ParameterStatus(nm, True, False, rd, cn))
        elif i_ok:  # excluded earlier, independent now: it still was not calibrated
            out.append(ident.ParameterStatus(nm, False, True, rd, cn))
        else:
            out.append(ident.ParameterStatus(nm, False, i_dep, rd, cn))
    return out
