"""Algorithm 2 of the report (section 5), one round of it: the linearized
iterative least squares on the identifiable parameters, read top to bottom in
:meth:`Stepping.iterate`:

1. evaluate: ``r, W = model.evaluate(xi)`` (:meth:`Stepping.evaluate`);
2. scale: ``H = diag(1/||W_R[:, i]||)`` (eq. 47), and classify: a column that
   vanished as the model fits is not identifiable after all (:meth:`Stepping._factor`);
3. weight: ``L`` from the channel sigmas (eq. 51; :mod:`~calibration.solver.weighting`,
   :meth:`Stepping._reweighed`);
4. step: the damped least-squares step ``z`` of ``[G W_R H] z ~ G r`` (eq. 48),
   ``d_R = H z`` (eq. 49), from the iteration's factorization;
5. damp: a step that raises the weighted cost is rejected and retried more damped,
   an accepted one relaxes the damping (``SolverOptions.adaptive``);
6. record: the variance (eq. 52) and the condition number (:meth:`Stepping._record`);
7. stop: ``max |d_R| < epsilon``, or the iteration limit.

The speed-ups each live in a module of their own, named for what they save:
:mod:`~calibration.solver.factored` (one QR per iteration for every damping, the
singular values deferred behind a Frobenius bound, the block-wise QR of tall
matrices), :mod:`~calibration.solver.retries` (the Levenberg-Marquardt safeguard:
parabolic retry, gain-ratio relaxation, stall check), :mod:`~calibration.solver.stopping`
(the predicted last step, the pooled round's early switch),
:mod:`~calibration.solver.history` (the record's variance and condition number
formed when read). Here, only: the observation matrix is let go before the model
is evaluated at a trial point where it is large (:data:`RELEASE_BYTES`).
The rounds around this (identifiability at the solution, per-channel weights,
the restart on the other path) are :mod:`~calibration.solver.rounds`.
:class:`Stepping` is a mixin of :class:`calibration.solver.rounds.Algorithm2`: it
works on that run's state, see there.
"""
from __future__ import annotations

import math

import numpy as np

from calibration import rowblocks
from calibration.errors import CalibrationError
from calibration.solver.factored import Scaled
from calibration.solver.history import Iteration
from calibration.solver.retries import GOOD_GAIN, Safeguard
from calibration.solver.stopping import LINEARIZATION_WATCH, Stopping

#: an observation matrix larger than this (bytes) is let go before the model is
#: evaluated at a trial point, and evaluated again at the current one where the step is
#: rejected (:meth:`Stepping.iterate`): one matrix of the fit's size alive, not two
#: (a 100 000-pose motion capture's is 460 MB)
RELEASE_BYTES = 64 << 20


class Stepping(Stopping, Safeguard):
    """The iteration of Algorithm 2 (mixin of :class:`calibration.solver.rounds.Algorithm2`):
    :meth:`iterate`, then the steps it is made of, in the order it uses them. The
    stopping rules beyond epsilon are :class:`~calibration.solver.stopping.Stopping`'s,
    the damping's safeguard :class:`~calibration.solver.retries.Safeguard`'s."""

    def iterate(self, early: bool = False) -> tuple[bool, str]:
        """Iterate on the current active set until the step is below epsilon, or
        until a step after which the next is predicted below it (taken without
        evaluating the model there: :meth:`~.stopping.Stopping._predicted_last`;
        ``self.settled`` then set, and the next round evaluates it first).

        ``early`` (pooled mode only): also stop before a step, with
        ``self.stopped_early`` and ``self.r_pred`` set and nothing recorded,
        once the residual that step's linearization predicts is reliable
        (``EARLY_SWITCH``)."""
        opt = self.opt
        eps, adaptive, max_iter = opt.epsilon, opt.adaptive, opt.max_iter
        rejected = 0
        # Adaptive damping (the Levenberg-Marquardt safeguard, :mod:`~calibration.solver.retries`):
        # a rejected step is retried more damped and shorter; accepted steps relax the
        # damping tenfold, by their gain ratio once it swings (``cautious``).
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
            failed = self._evaluate_settled()
            if failed:
                return False, failed
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
                if self._switch_early(F, z, zn, lam2, r_lin, pred):
                    self.stopped_early, self.r_pred = True, r_lin
                    self.lin_err = lin_err
                    self.next_factor = F  # the resumed round starts here (same weights)
                    return True, ""
            # (after the early stop: where both would end the pooled round there, the
            # early stop's resumed round needs no evaluation at a new point)
            settle = (self._predicted_last(F, z, lam2, step, taken, eps, r_lin, lin_err)
                      if last else False)
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
                    self.lam_eff = self._retried(F, z, lam2, cost, cost_try if ok else None)
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
