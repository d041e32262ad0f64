"""The result of Algorithm 2 (:class:`CalibrationResult`) and the final
statistics at the solution: sigma (eq. 51), covariance and condition number
(eq. 52), reusing a QR already made there, and the parameters' status.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from calibration import identifiability as ident
from calibration import rowblocks
from calibration.solver.factored import formed_condition, gesvd, masks, trtri
from calibration.solver.history import Iteration


@dataclass(frozen=True)
class CalibrationResult:
    """Everything a caller needs (after scipy's OptimizeResult).

    x, std:        ``(N,)`` calibrated values and standard deviations (NaN std
                   for parameters that were not calibrated).
    covariance:    ``(N_R, N_R)`` over ``covariance_names``.
    status:        per parameter :class:`calibration.identifiability.ParameterStatus`.
    converged, message, iterations, nfev: how it ended.
    rounds:        the rounds of Algorithm 2 that reached a solution (weights
                   re-estimated, or parameters dropped, in between).
    sigma:         channel -> estimated sigma of one row (eq. 51), residual units.
    sigma_dof:     channel -> degrees of freedom of its estimated sigma (none where
                   known, nor where the fit is exact: every channel's residual at
                   round-off, ``weighting.ROUNDOFF_SIGMA``); the covariance adds
                   that sigma's own uncertainty
                   (:meth:`~calibration.solver.weighting.Weighting.covariance_sigma`).
    residual_rms:  channel -> RMS of the final residual.
    condition_number: of the final scaled, weighted observation matrix (formed
                   when first read, from the last iteration's triangle where it
                   was made there: most callers of the solver never read it).
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
    # the condition number, or the (n, n) triangle whose it is (:attr:`condition_number`)
    _condition: object = field(repr=False)
    cost: float
    history: tuple[Iteration, ...] = field(repr=False)
    n_rows: int = 0
    wall_time: float = 0.0
    sigma_dof: dict = field(default_factory=dict)
    rounds: int = 0

    @property
    def condition_number(self) -> float:
        return formed_condition(self, "_condition")

    @property
    def n_identifiable(self) -> int:
        return sum(s.identifiable for s in self.status)

    def value(self, name: str) -> float:
        return float(self.x[self.names.index(name)])

    def error_of(self, name: str) -> float:
        return float(self.std[self.names.index(name)])


def make_result(run, converged: bool, message: str, t_start: float,
                rounds: int = 0) -> CalibrationResult:
    """The result of ``run`` (:class:`calibration.solver.rounds.Algorithm2`)
    at its solution: final statistics (eqs. 51, 52)."""
    opt, model = run.opt, run.model
    names, active, rows, r = run.names, run.active, run.rows, run.r
    sigma = (dict(run.known) if run.all_known else run.channel_sigma(r, run.n_active))
    w_cov = run.row_weights(sigma)
    status = _final_status(run, sigma if opt.weight_errors else None,
                           w_cov if opt.weight_errors else np.ones(rows))
    dof = {} if run.all_known else dict(run.sigma_dof)
    f = None  # channel -> factor of the sigma the covariance is made with
    if opt.weight_errors and dof:
        cov_sigma = run.covariance_sigma(sigma)
        f = {ch: cov_sigma[ch] / sigma[ch] for ch in dof}
    # one factor for every channel: a scale of the covariance at sigma; else the
    # covariance at the inflated sigma, and only the condition number at sigma
    scale = f is not None and len(f) == len(run.channels) and len(set(f.values())) == 1
    cov, cond = _covariance(run, sigma, w_cov, need_cov=f is None or scale)
    if scale:
        cov = cov * next(iter(f.values())) ** 2
    elif f is not None:
        cov = _covariance(run, cov_sigma, run.row_weights(cov_sigma), need_cond=False)[0]
    std = np.full(len(names), np.nan)
    std[active] = np.sqrt(np.maximum(cov.diagonal(), 0.0))
    rss = np.bincount(run.row_channel, weights=r * r, minlength=len(run.channels)).tolist()
    rms = {ch: math.sqrt(s / nc) if nc else math.nan
           for ch, s, nc in zip(run.channels, rss, run.channel_count.tolist())}
    if converged:
        message = (f"converged in {run.k} iterations (max step < {opt.epsilon:g}"
                   + (": predicted for the step after the last)" if run.settled else ")"))
    return CalibrationResult(
        method=model.method, names=names, x=run.x, x0=run.x0, std=std, covariance=cov,
        covariance_names=tuple(nm for nm, a in zip(names, active) if a),
        status=tuple(status), converged=converged, message=message, iterations=run.k,
        nfev=run.nfev, sigma=sigma, sigma_known=run.all_known, residual_rms=rms,
        residual=r, _condition=cond, cost=0.5 * float(r @ (w_cov * r)),
        history=tuple(run.history), n_rows=rows, wall_time=time.perf_counter() - t_start,
        sigma_dof=dof, rounds=rounds)


# (cond * column-norm spread)^2 below which the covariance is taken from the QR
# of the scaled matrix; above it, as the normal matrix nears 1/eps, the
# pseudo-inverse of the normal matrix (what eq. 52 reads) cuts singular values.
_PINV_SAFE = 1e13


def _covariance(run, sigma, w, need_cond=True, need_cov=True):
    """Covariance ``(W_R^T L W_R)^-1`` (eq. 52) and the condition number of the
    scaled, weighted ``G W_R H`` at the solution, ``L = diag(w)`` (``w`` from
    ``sigma``), from a QR already made there where possible: the last
    iteration's (weights proportional to ``w``: known sigma, one sigma for all
    rows) or the identifiability recheck's (same weights; its unit columns
    differ from ``G W_R H`` by a column scaling only); else a QR of ``G W_R H``.
    Either way ``H (R^T R)^-1 H``. Where the normal matrix is so
    ill-conditioned that a pseudo-inverse would cut singular values it is that
    pseudo-inverse, as eq. 52 reads. The condition number is returned as the
    last iteration's triangle where that QR serves and its singular values were
    not needed to choose (:func:`~calibration.solver.factored.formed_condition` forms
    it). ``need_cond`` False: the condition number
    is not asked for (the second value is then NaN where it was not needed to
    choose between the two); ``need_cov`` False: only the condition number is
    asked for (the covariance returned may then be None)."""
    scale = run.opt.scale_columns
    # W_R, the calibrated columns, is taken a block of rows at a time (rowblocks)
    W, cols = run.W, None if run.all_active else run.active_idx
    rows, n = W.shape[0], run.n_active
    F = run.last_factor
    if F is not None and F.key is run.W_key and F.svd is None and F.Rinv is not None:
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
            if F.cond_below(math.sqrt(_PINV_SAFE) / spread):  # w = c g^2: G W_R H = sqrt(c) A
                Rh = F.Rinv * h[:, None]
                return (Rh @ Rh.T) * (1.0 / c), F.cond_or_triangle
    norms = rowblocks.column_norms(W, cols)
    h = 1.0 / norms if scale else np.ones(n)
    blocks = rowblocks.spans(rows, n)
    sw = np.sqrt(w)

    def scaled(lo, hi):  # rows lo:hi of G W_R H, in Fortran order
        return np.multiply(rowblocks.rows_of(W, lo, hi, cols) * h, sw[lo:hi, None],
                           out=np.empty((hi - lo, n), order="F"))

    if n and rows > n and norms.min() > 0:
        chk = run.last_check
        if (chk is not None and chk.R is not None and chk.saw(run, sigma)
                and chk.cls[0].tobytes() == run.active.tobytes()):  # (bool masks)
            # the recheck's R is that of G W_R D, D = 1/||G W_R[:, j]||: G W_R H = (G W_R D) S
            # with S = diag(||G W_R[:, j]|| h_j), so R S is the triangle of G W_R H
            R = chk.R * (chk.cls[3][run.active_idx] * h)
        else:
            qr, _tau, _work, info = rowblocks.stacked_qr(scaled, blocks, n)
            R = qr[:n, :n] * masks(n)[0][:, :n] if info == 0 else None
        if R is not None and not need_cond:
            # ||R||_F ||R^-1||_F >= cond(R): where that bound (with a factor 2 to
            # spare) is below the limit so is the condition number, and the
            # singular values are not needed to choose the QR
            Rinv, info = trtri(R)
            if info == 0:
                spread = float(norms.max() / norms.min()) if scale else 1.0
                rf, vf = R.ravel(order="K"), Rinv.ravel(order="K")
                bound = math.sqrt(float(rf @ rf) * float(vf @ vf))
                if (2 * bound * spread) ** 2 < _PINV_SAFE:
                    Rh = Rinv * h[:, None]
                    return Rh @ Rh.T, math.nan
        if R is not None:
            svl = gesvd(R, compute_uv=0)[1].tolist()
            if all(math.isfinite(v) for v in svl) and svl[-1] > 0:
                cond = svl[0] / svl[-1]
                spread = float(norms.max() / norms.min()) if scale else 1.0
                if (cond * spread) ** 2 < _PINV_SAFE:
                    if not need_cov:
                        return None, cond
                    Rinv, info = trtri(R)
                    if info == 0:
                        Rh = Rinv * h[:, None]
                        return Rh @ Rh.T, cond
    if len(blocks) == 1:
        WA = rowblocks.rows_of(W, 0, rows, cols)
        cov = np.linalg.pinv(WA.T @ (WA * w[:, None]))
        sv = np.linalg.svd((WA * h) * np.sqrt(w)[:, None], compute_uv=False)
    else:  # (the singular values of G W_R H are those of its triangle)
        cov = np.linalg.pinv(rowblocks.gram(W, cols, w))
        sv = np.linalg.svd(rowblocks.triangle(scaled, blocks, n), compute_uv=False)
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
    rg = np.sqrt(weights) * run.r if opt.recheck else None  # the weighted residual
    # the residual's part of zero_floor (kappa times the weighted residual's norm)
    res_floor = opt.kappa * math.sqrt(float(rg @ rg)) if opt.recheck else None
    if opt.recheck and chk is not None and chk.saw(run, sigma):
        ok, dep, rdiag, norms = chk.cls
        extra = run.candidates & ~chk.candidates
        if not extra.any():
            cls = chk.cls
        else:
            # a zero column is left out of the QR, and so changes nothing, if it
            # does not raise the largest candidate norm (the rank floor) either
            floor_rank = ident.zero_floor(norms, opt.rank_tol, chk.candidates)
            floor = max(floor_rank, res_floor)  # zero_floor(..., rg, kappa)
            ne = norms[extra].tolist()
            if all(v <= floor for v in ne) and opt.rank_tol * max(ne) <= floor_rank:
                cls = chk.cls
    if cls is None:
        cls = ident.classify(run.W, weights=weights, candidates=run.candidates,
                             residual=run.r if opt.recheck else None,
                             rank_tol=opt.rank_tol, kappa=opt.kappa,
                             order=run.model.identify_order)
    ok, dep, rdiag, norms = cls
    # a fixed parameter's column against the zero floor of the classification
    # (rank and, at the solution, the residual): strong, a wrong value biases the others
    cand = run.candidates
    floor = ident.zero_floor(norms, opt.rank_tol, cand)
    if res_floor is not None:
        floor = max(floor, res_floor)  # zero_floor(..., rg, kappa)
    out = []
    status = ident.ParameterStatus.of
    for nm, a, c, i_ok, i_dep, rd, cn in zip(run.names, run.active.tolist(), cand.tolist(),
                                             ok.tolist(), dep.tolist(), rdiag.tolist(),
                                             norms.tolist()):
        if a:
            out.append(status(nm, True, False, rd, cn))
        elif not c:
            out.append(status(nm, False, bool(cn > floor), rd, cn, True))
        elif i_ok:  # excluded earlier, independent now: it still was not calibrated
            out.append(status(nm, False, True, rd, cn))
        else:
            out.append(status(nm, False, i_dep, rd, cn))
    return out
