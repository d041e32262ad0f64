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
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

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


def _channel_sigma(model, r, n_active, known=None, pooled=False):
    """Sigma of one row per channel (eq. 51): known values where given; else
    estimated from the residual, pooled over all rows (the report's single
    sigma) or per channel with its share of the degrees of freedom."""
    n = len(r)
    out = {}
    if pooled:
        dof = n - n_active
        s = float(np.sqrt(np.sum(r ** 2) / dof)) if dof > 0 else float(np.sqrt(np.mean(r ** 2)))
        return {ch: max(s, SIGMA_FLOOR) for ch in model.channels}
    for c, ch in enumerate(model.channels):
        if known and ch in known:
            out[ch] = float(known[ch])
            continue
        sel = model.row_channel == c
        nc = int(sel.sum())
        dof = nc - n_active * nc / n
        rss = float(np.sum(r[sel] ** 2))
        out[ch] = max(np.sqrt(rss / dof) if dof > 0 else np.sqrt(rss / max(nc, 1)), SIGMA_FLOOR)
    return out


def _weights(model, sigma):
    s = np.array([sigma[ch] for ch in model.channels])[model.row_channel]
    return 1.0 / s ** 2


class _Algorithm2:
    """State of one run of Algorithm 2 (see module doc)."""

    def __init__(self, model: MeasurementModel, opt: SolverOptions, callback):
        self.model, self.opt, self.callback = model, opt, callback
        self.lam = model.default_damping if opt.damping is None else float(opt.damping)
        self.names = tuple(model.names)
        self.x0 = np.array(model.x0, dtype=float)
        self.x = self.x0.copy()
        known = dict(opt.sigma) if opt.sigma else {}
        unknown = set(known) - set(model.channels)
        if unknown:
            raise CalibrationError(f"sigma given for unknown channel(s) {sorted(unknown)} "
                                   f"(method {model.method} has {list(model.channels)})")
        for ch, v in known.items():
            if not (np.isfinite(v) and v > 0):
                raise CalibrationError(f"sigma of channel {ch!r} must be a positive number, not {v!r}")
        self.known = known
        self.all_known = set(known) == set(model.channels)
        # weighting mode: 'known' (trace sigma), 'pooled' (eq. 51 during the
        # iteration), 'channel' (per-channel sigma fixed from the last solution)
        self.mode = "known" if self.all_known else "pooled"
        self.r, self.W = model.evaluate(self.x)
        self.nfev = 1
        self.rows = len(self.r)
        if not (np.all(np.isfinite(self.r)) and np.all(np.isfinite(self.W))):
            raise CalibrationError("the model gives non-finite values at the start parameters")
        self.sigma = (dict(known) if self.all_known else {ch: 1.0 for ch in model.channels})
        self.weights = self._weights_now()
        self.candidates = np.array([nm not in opt.fixed for nm in self.names])
        self.history: list[Iteration] = []
        self.k = 0
        self.lam_eff = self.lam
        self.cond = np.nan

    def _weights_now(self):
        if not self.opt.weight_errors:
            return np.ones(self.rows)
        return _weights(self.model, self.sigma)

    def evaluate(self, x):
        self.nfev += 1
        return self.model.evaluate(x)

    # -- identifiability ------------------------------------------------------
    def initial_status(self):
        model, opt = self.model, self.opt
        twin = model.consistent_twin(self.x)
        if twin is model:
            status = ident.analyze(self.W, self.names, weights=self.weights,
                                   candidates=self.candidates, rank_tol=opt.rank_tol)
        else:
            r_t, W_t = twin.evaluate(self.x)
            self.nfev += 1
            status = ident.analyze(W_t, self.names, candidates=self.candidates, residual=r_t,
                                   rank_tol=opt.rank_tol, kappa=opt.kappa)
        self.active = np.array([s.identifiable for s in status])
        na = int(self.active.sum())
        if na == 0:
            raise CalibrationError("no parameter can be identified from these measurements")
        # parameters the measurements depend on at all; with too few rows the
        # rank is limited by the data, not by the method, and sigma (eq. 51)
        # needs at least one degree of freedom
        n_dep = sum(1 for s in status if s.identifiable or s.influences_model)
        if self.rows <= n_dep:
            p = max(model.p, 1)
            raise CalibrationError(
                f"{model.n_poses} poses give {self.rows} equations for up to {n_dep} parameters; "
                f"at least {int(np.ceil((n_dep + 1) / p))} poses are needed "
                f"(recommended {ident.minimum_poses(n_dep, p)}, eq. 60)")

    def solution_weights(self):
        """Per-channel weights from the residual at the current parameters."""
        if not self.opt.weight_errors:
            return np.ones(self.rows)
        return _weights(self.model, _channel_sigma(self.model, self.r, int(self.active.sum()),
                                                   self.known))

    def recheck(self) -> bool:
        """Identifiability at the solution; True if parameters were dropped."""
        opt = self.opt
        status = ident.analyze(self.W, self.names, weights=self.solution_weights(),
                               candidates=self.active & self.candidates, residual=self.r,
                               rank_tol=opt.rank_tol, kappa=opt.kappa)
        new_active = np.array([s.identifiable for s in status]) & self.active
        if np.array_equal(new_active, self.active):
            return False
        self.drop(self.active & ~new_active)
        return True

    def drop(self, mask):
        """Stop calibrating ``mask``; they return to their start values, or stay
        where they are if the model cannot be evaluated there."""
        self.active = self.active & ~mask
        x = self.x.copy()
        x[mask] = self.x0[mask]
        try:
            self.r, self.W = self.evaluate(x)
            self.x = x
        except CalibrationError:
            self.r, self.W = self.evaluate(self.x)

    def reweight(self) -> bool:
        """Per-channel weights at the solution; True if they changed materially."""
        if self.mode == "known" or not self.opt.weight_errors or len(self.model.channels) < 2:
            return False
        sigma = _channel_sigma(self.model, self.r, int(self.active.sum()), self.known)
        old = self.sigma
        self.sigma, self.mode = sigma, "channel"
        self.weights = self._weights_now()
        floor = all(v <= 10 * SIGMA_FLOOR for v in sigma.values())
        return not floor and any(abs(sigma[ch] / old[ch] - 1) > 0.05 for ch in sigma)

    # -- iteration -------------------------------------------------------------
    def _record(self, d, step, sv, Vt, h, g, cost):
        """History entry: variance of the estimate at this iteration (eq. 52,
        from the SVD of the scaled, weighted matrix) and its condition number."""
        self.cond = float(sv[0] / sv[-1]) if sv[-1] > 0 else np.inf
        w_cov = _weights(self.model, self.sigma)
        factor = float(g[0] ** 2 / w_cov[0]) if self.mode == "pooled" or not self.opt.weight_errors else 1.0
        inv = np.where(sv > sv[0] * 1e-15, 1 / sv ** 2, 0.0)
        var = np.full(len(self.names), np.nan)
        var[self.active] = factor * h ** 2 * np.einsum("ij,i->j", Vt ** 2, inv)
        it = Iteration(self.x.copy(), var, self.cond, step, cost, dict(self.sigma))
        self.history.append(it)
        if self.callback is not None:
            self.callback(self.k, it)

    def iterate(self) -> tuple[bool, str]:
        """Iterate on the current active set until the step is below epsilon."""
        opt, model = self.opt, self.model
        rejected = 0
        self.lam_eff = self.lam
        while self.k < opt.max_iter:
            active = self.active
            WA = self.W[:, active]
            norms = np.linalg.norm(WA, axis=0)
            lost = norms <= opt.rank_tol * norms.max()
            if lost.any():
                # a column that vanishes as the model fits the data (e.g. q2_off
                # of sm-self-redundancy): not identifiable after all
                mask = np.zeros_like(active)
                mask[np.flatnonzero(active)[lost]] = True
                self.drop(mask)
                continue
            h = 1.0 / norms if opt.scale_columns else np.ones(WA.shape[1])
            g = np.sqrt(self.weights)
            A = (WA * h) * g[:, None]
            b = g * self.r
            # one thin SVD gives the damped step for any lambda (eq. 48), the
            # condition number and the variance (eq. 52)
            try:
                U, sv, Vt = np.linalg.svd(A, full_matrices=False)
            except np.linalg.LinAlgError:
                return False, f"the observation matrix is not finite at iteration {self.k + 1}"
            Ub = U.T @ b
            cost = 0.5 * float(b @ b)
            lam2 = self.lam_eff ** 2
            filt = sv / (sv * sv + lam2) if lam2 > 0 else np.where(sv > sv[0] * 1e-15, 1 / sv, 0.0)
            d = h * (Vt.T @ (filt * Ub))
            step = float(np.max(np.abs(d))) if d.size else 0.0
            if not np.all(np.isfinite(d)):
                return False, f"the step became non-finite at iteration {self.k + 1}"
            if step < opt.epsilon:  # converged: the step is below the tolerance
                self.k += 1
                self._record(d, step, sv, Vt, h, g, cost)
                return True, ""
            x_try = self.x.copy()
            x_try[active] += d
            try:
                r_try, W_try = self.evaluate(x_try)
                ok = bool(np.all(np.isfinite(r_try)) and np.all(np.isfinite(W_try)))
            except CalibrationError:  # e.g. the PM cannot assemble there
                ok, r_try, W_try = False, None, None
            worse = not ok or 0.5 * float(np.sum(self.weights * r_try ** 2)) > cost * (1 + 1e-12)
            if opt.adaptive and worse:
                rejected += 1
                if rejected > 30:
                    return False, f"no step lowers the cost any more (iteration {self.k + 1})"
                self.lam_eff = max(10 * self.lam_eff, 1e-3 * float(sv[0]))
                continue
            if not ok:
                return False, f"the step left the model's domain at iteration {self.k + 1}"
            rejected = 0
            self.lam_eff = max(self.lam, self.lam_eff / 10)
            self.x, self.r, self.W = x_try, r_try, W_try
            self.k += 1
            if self.mode == "pooled":  # eq. 51, one sigma for all rows
                self.sigma = _channel_sigma(model, self.r, int(active.sum()), pooled=True)
            self._record(d, step, sv, Vt, h, g, cost)
            self.weights = self._weights_now()
            if step < opt.epsilon:
                return True, ""
        return False, f"no convergence within {opt.max_iter} iterations"


def solve(model: MeasurementModel, options: SolverOptions | None = None,
          callback=None) -> CalibrationResult:
    """Run Algorithm 2 on ``model``; ``callback(k, Iteration)`` after each iteration."""
    opt = options or SolverOptions()
    t_start = time.perf_counter()
    run = _Algorithm2(model, opt, callback)
    run.initial_status()
    converged, message = False, ""
    for _ in range(6):
        converged, message = run.iterate()
        if not converged:
            break
        changed = run.recheck() if opt.recheck else False
        changed = run.reweight() or changed
        if not changed:
            break
    # final statistics at the solution (eqs. 51, 52)
    names, active, rows = run.names, run.active, run.rows
    sigma = (dict(run.known) if run.all_known else
             _channel_sigma(model, run.r, int(active.sum()), run.known))
    w_cov = _weights(model, sigma)
    status = _final_status(run, w_cov if opt.weight_errors else np.ones(rows))
    WA = run.W[:, active]
    cov = np.linalg.pinv(WA.T @ (WA * w_cov[:, None]))
    std = np.full(len(names), np.nan)
    std[active] = np.sqrt(np.clip(np.diag(cov), 0, None))
    r = run.r
    rms = {ch: float(np.sqrt(np.mean(r[model.row_channel == c] ** 2)))
           for c, ch in enumerate(model.channels)}
    h = 1.0 / np.linalg.norm(WA, axis=0) if opt.scale_columns else np.ones(WA.shape[1])
    sv = np.linalg.svd((WA * h) * np.sqrt(w_cov)[:, None], compute_uv=False)
    cond = float(sv[0] / sv[-1]) if sv.size and sv[-1] > 0 else np.inf
    if converged:
        message = f"converged in {run.k} iterations (max step < {opt.epsilon:g})"
    return CalibrationResult(
        method=model.method, names=names, x=run.x, x0=run.x0, std=std, covariance=cov,
        covariance_names=tuple(nm for nm, a in zip(names, active) if a),
        status=tuple(status), converged=converged, message=message, iterations=run.k,
        nfev=run.nfev, sigma=sigma, sigma_known=run.all_known, residual_rms=rms,
        residual=r, condition_number=cond, cost=0.5 * float(r @ (w_cov * r)),
        history=tuple(run.history), n_rows=rows, wall_time=time.perf_counter() - t_start)


def _final_status(run, weights):
    """Classification reported to the operator: identifiable = calibrated; the
    others classified by their columns at the solution (zero column: no
    influence; dependent: influences the model)."""
    opt = run.opt
    at_solution = ident.analyze(run.W, run.names, weights=weights, candidates=run.candidates,
                                residual=run.r if opt.recheck else None,
                                rank_tol=opt.rank_tol, kappa=opt.kappa)
    out = []
    for j, s in enumerate(at_solution):
        if run.active[j]:
            out.append(ident.ParameterStatus(s.name, True, False, s.r_diag, s.column_norm))
        elif s.identifiable:  # excluded earlier, independent now: it still was not calibrated
            out.append(ident.ParameterStatus(s.name, False, True, s.r_diag, s.column_norm))
        else:
            out.append(s)
    return out
