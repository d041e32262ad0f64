"""The rounds of Algorithm 2 and identifiability (:func:`solve`), and its restart on the
other path. Identifiability is analysed at the start (structural dependencies) and
again at the solution (:mod:`calibration.identifiability`): parameters found
non-identifiable there return to their start values and the iteration resumes
without them; the per-channel weights are re-estimated at each solution."""
from __future__ import annotations

import math
import time
from dataclasses import replace

import numpy as np
from scipy import special

from calibration import identifiability as ident
from calibration.errors import CalibrationError
from calibration.model import MeasurementModel
from calibration.solver.factored import Scaled, clearly_identifiable
from calibration.solver.options import SolverOptions
from calibration.solver.result import CalibrationResult, make_result
from calibration.solver.step import Iteration, Stepping
from calibration.solver.weighting import Weighting


class Check:
    """An identifiability check at a solution (:meth:`Algorithm2.recheck`):
    its inputs (``key``: the observation matrix's, :attr:`Algorithm2.W_key`), its
    classification ``(identifiable, influences, r_diag, column_norm)`` and the
    triangle ``R`` of its QR (or None)."""

    __slots__ = ("R", "candidates", "cls", "key", "r", "sigma", "weights")

    def __init__(self, key, r, sigma, weights, candidates, cls, R):
        self.key, self.r, self.sigma, self.weights = key, r, sigma, weights
        self.candidates, self.cls, self.R = candidates, cls, R

    def saw(self, run, sigma) -> bool:
        """Did this check see the final solution of ``run``, weighted by ``sigma``
        (None: unweighted)?"""
        return (self.key is run.W_key and self.r is run.r
                and (self.sigma == sigma if sigma is not None and self.sigma is not None
                     else np.array_equal(self.weights, run.row_weights(sigma) if sigma else
                                         np.ones(run.rows))))


class Algorithm2(Weighting, Stepping):
    """State of one run of Algorithm 2: the rounds and identifiability here,
    the error weighting from :class:`Weighting`, the iteration from
    :class:`Stepping`."""

    def __init__(self, model: MeasurementModel, opt: SolverOptions, callback,
                 other_path: bool = False):
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
        # iteration), 'channel' (per-channel sigma fixed from the last solution).
        # Where every sigma is stated and the same for every channel, the first round
        # is pooled all the same (L = I at the first iteration, then eq. 51's one
        # sigma, as the report's Algorithm 2 runs; the stated weights are its weights
        # times a constant, the same minimum), and the stated sigma weigh the rows from
        # its solution on (:meth:`~calibration.solver.weighting.Weighting.reweight`):
        # weighted by 1/sigma from the first step, lambda damps nothing (a stated
        # 1e-5 m puts the scaled matrix's singular values near 1e5), and undamped
        # Gauss-Newton steps from a far start led into local minima and long swings
        # the pooled round's damping avoids (512 fits of the test data sets and AGEBOT's
        # robot file, noise stated: the same minima, 7133 evaluations against 4411;
        # sm-distance 3863 against 1279; docs/methods.md). Stated sigmas that differ between
        # channels weigh the rows from the first step: one sigma for a distance in
        # metres and a tilt in radians led sm-distance-tilt into local minima more
        # often (17 restarts in 150 Monte Carlo runs against 9). ``other_path``: the
        # other of the two (the restart's, :func:`solve`).
        self.pooled_first = (self.all_known and bool(opt.weight_errors)
                             and self.stated_uniform() != bool(other_path))
        self.mode = ("known" if self.all_known and not self.pooled_first else "pooled")
        self.r, self.W = model.evaluate(self.x)
        # the observation matrix's identity (the point it was evaluated at: a large one
        # let go and evaluated there again is the same, Stepping.iterate) and that point
        self.W_key, self.W_at = object(), self.x
        self.nfev = 1
        self.rows = len(self.r)
        if not (math.isfinite(float(self.r.sum()) + float(self.W.sum()))
                or (np.all(np.isfinite(self.r)) and np.all(np.isfinite(self.W)))):
            raise CalibrationError("the model gives non-finite values at the start parameters")
        self.row_channel = np.asarray(model.row_channel, dtype=np.intp)
        self.channel_count = np.bincount(self.row_channel, minlength=len(channels))
        self.ch0 = channels[self.row_channel[0]] if self.rows else None
        self.sigma = dict(known) if self.mode == "known" else dict.fromkeys(channels, 1.0)
        self._g_sigma = None  # the sigma dict self.g was made from
        self._set_weights()
        fixed = opt.fixed
        self.candidates = (np.array([nm not in fixed for nm in self.names]) if fixed
                           else np.ones(len(self.names), bool))
        self.history: list[Iteration] = []
        self.k = 0
        self.lam_eff = self.lam
        self.stopped_early = False
        self.r_pred = None  # residual predicted at the pooled solution (early stop)
        self.last_check = None  # the last recheck (Check)
        self.last_factor = None  # the factorization the last iteration ended on
        self.next_factor = None  # the factorization the next iteration starts from, if made
        self.lin_err = None  # the last step's linearization error, carried as taken
        self.taken: list = []  # steps accepted in a row in the current round (Stepping.iterate)
        self.can_settle = bool(getattr(model, "evaluates_everywhere", False))
        self.settled = False  # x the last step's, not evaluated (r predicted, W the point before)
        self._sigma_memo = (None, -1, None, None)
        self.sigma_dof: dict = {}  # channel -> degrees of freedom of its estimated sigma
        self.sigma_shared = False  # a channel had no degrees of freedom: one sigma from then on
    # -- identifiability ------------------------------------------------------
    def initial_status(self):
        model, opt = self.model, self.opt
        twin = model.consistent_twin(self.x)
        if twin is model:
            g = self.g  # the first iteration's weights (L = I, or the trace's sigma)
            cls = self._first_factor_status(g)
            if cls is None:
                cls = ident.classify(self.W, row_scale=g, candidates=self.candidates,
                                     rank_tol=opt.rank_tol, order=model.identify_order)
        else:
            r_t, W_t = twin.evaluate(self.x)
            self.nfev += 1
            cls = ident.classify(W_t, candidates=self.candidates, residual=r_t,
                                 rank_tol=opt.rank_tol, kappa=opt.kappa,
                                 order=model.identify_order)
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

    def _natural_order(self) -> bool:
        """Are the columns judged in parameter order (the order of the solver's QR)?"""
        order = self.model.identify_order
        return order is None or np.array_equal(order, np.arange(len(order)))

    def _first_factor_status(self, g):
        """The start classification from the first iteration's factorization:
        ``(identifiable, influences)`` where the candidates' columns above
        classify's zero floor are all clearly identifiable there
        (:func:`~calibration.solver.factored.clearly_identifiable`; the other
        candidates have no influence, and the parameters fixed by the options
        are neither, as classify reports them), the factorization kept for the
        first iteration (:attr:`next_factor`); else None (then
        :func:`calibration.identifiability.classify` decides).

        The QR of ``[G W_R H, G r]`` the first iteration makes holds that of the
        unit columns the classification factors (the same matrix up to a column
        scaling). Its column norms and zero floor are classify's own (the floor
        over the candidates' columns); ``g``: the weights' square roots it classifies
        with (a float, or one per row)."""
        if not self._natural_order():
            return None
        cand = self.candidates
        every = bool(cand.all())
        norms, floor = ident.column_floor(self.W, self.opt.rank_tol, None if every else cand,
                                          row_scale=g)
        use = norms > floor
        if not every:
            use &= cand
        if not use.any():
            return None
        self._set_active(use)
        try:
            F = self._factor()
        except np.linalg.LinAlgError:
            return None
        if (not isinstance(F, Scaled) or F.Rinv is None
                or clearly_identifiable(F, self.opt.rank_tol, norms[self.active_idx],
                                        float(floor)) is None):
            return None
        self.next_factor = F
        return use, np.zeros(len(use), bool)

    def _check_from_last(self, r, sigma, weights, cand):
        """The identifiability check at the solution from the last iteration's
        factorization, where its weights and the check's are both the same for
        every row (one channel, or channels whose sigmas agree): a
        :class:`Check`, where every active parameter is clearly identifiable
        there (:func:`~calibration.solver.factored.clearly_identifiable`, with
        classify's column norms and zero floor at the solution); else None."""
        F = self.last_factor
        if (F is None or F.key is not self.W_key or F.Rinv is None or F.svd is not None
                or not isinstance(F.g, float) or F.n != self.n_active
                or (sigma is not None and len(set(sigma.values())) > 1)
                or cand.tobytes() != self.active.tobytes() or not self._natural_order()):
            return None
        opt = self.opt
        # classify's column norms and zero floor
        gw = np.sqrt(weights)
        norms, floor = ident.column_floor(self.W, opt.rank_tol, cand, gw * r, opt.kappa,
                                          row_scale=gw)
        d = clearly_identifiable(F, opt.rank_tol, norms[self.active_idx], float(floor))
        if d is None:
            return None
        rdiag = np.zeros(len(cand))
        rdiag[self.active_idx] = d
        cls = (cand.copy(), np.zeros(len(cand), bool), rdiag, norms)
        return Check(self.W_key, r, sigma, weights, cand, cls, None)

    def _set_active(self, mask):
        self.active = np.asarray(mask, bool)
        self.active_idx = np.flatnonzero(self.active)
        self.n_active = len(self.active_idx)
        self.all_active = self.n_active == len(self.active)

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
        chk = self.last_check
        if not (chk is not None and chk.key is self.W_key and chk.r is r and chk.sigma == sigma
                and chk.candidates.tobytes() == cand.tobytes()):  # (bool masks)
            # (a round that ended where it began, e.g. after the per-channel
            # weights of a noise-free fit changed at round-off: the same check)
            chk = self._check_from_last(r, sigma, weights, cand)
            if chk is None:
                *cls, R = ident.classify(self.W, weights=weights, candidates=cand, residual=r,
                                         rank_tol=opt.rank_tol, kappa=opt.kappa, return_r=True,
                                         order=self.model.identify_order)
                chk = Check(self.W_key, r, sigma, weights, cand, cls, R)
            self.last_check = chk
        cls = chk.cls
        new_active = cls[0] & self.active
        if new_active.tobytes() == self.active.tobytes():  # (bool masks)
            return False
        self.drop(self.active & ~new_active)
        return True

    def drop(self, mask):
        """Stop calibrating ``mask``; they return to their start values, or stay
        where they are if the model cannot be evaluated there."""
        self._set_active(self.active & ~mask)
        if self.n_active == 0:
            raise CalibrationError(
                "no parameter can be identified at the solution: every column is within "
                f"kappa = {self.opt.kappa:g} times the residual there (the model does not "
                "fit the data: a local minimum, or a fixed parameter far from its value)")
        self.r_pred = self.next_factor = None
        self.settled = False
        x = self.x.copy()
        x[mask] = self.x0[mask]
        self._let_go()  # (a new matrix either way)
        try:
            self.r, self.W = self.evaluate(x)
            self.x = x
        except CalibrationError:
            self.r, self.W = self.evaluate(self.x)
        self.W_key, self.W_at = object(), self.x


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
    Where every sigma is stated and the same for every channel the first round
    is pooled too, and the stated sigma weigh the rows from its solution on
    (:class:`Algorithm2`); a fit that then does not explain its readings by the
    stated noise is run once more on the other path.
    """
    opt = options or SolverOptions()
    t_start = time.perf_counter()
    res, run = _solve(model, opt, callback, t_start)
    why = _restart_reason(res, run)
    if why is None:
        return res
    # every sigma known (a trace states its sensors' noise) and a fit that does not
    # explain the readings by it: a local minimum the first path led to, or a model or
    # data that do not fit. Once more on the other path (a first round pooled, or
    # weighted by the stated sigma from the first step: Algorithm2); the lower of the
    # two minima is the result.
    pooled_first = run.pooled_first
    del run  # (its observation matrix is let go before the restart makes its own)
    alt, failed = _restarted(model, opt, callback, t_start)
    nfev = res.nfev + (alt.nfev if alt is not None else 0)
    its = res.iterations + (alt.iterations if alt is not None else 0)
    other = ("weighted by the stated noise from its first step" if pooled_first
             else "with its first round pooled, as without a stated noise")
    if alt is not None and alt.converged and (not res.converged
                                              or alt.cost < res.cost * (1 - RESTART_GAIN)):
        # (iterations and history: the last fit's; nfev: every fit's)
        return replace(alt, nfev=nfev, wall_time=time.perf_counter() - t_start,
                       message=f"{alt.message} after a restart: the first fit {why}; the "
                       f"same fit {other} ended lower ({its} iterations, {nfev} "
                       "evaluations in all)")
    ended = (f"failed ({failed})" if failed else "did not converge"
             if alt is not None and not alt.converged else "ended no lower")
    return replace(res, nfev=nfev, wall_time=time.perf_counter() - t_start,
                   message=f"{res.message}; it {why}, and a restart {other} {ended} "
                   f"({its} iterations, {nfev} evaluations in all)")


#: a fit with every sigma known that does not converge, or converges with a
#: chi-square whose upper-tail probability at the stated noise is below this (where
#: the station's gate refuses a channel's residual, calibration.quality.CHI2_ALPHA),
#: is restarted (:func:`solve`)
RESTART_ALPHA = 1e-3
#: the restart's minimum replaces the first where its cost is lower by this fraction
RESTART_GAIN = 1e-6


def _restart_reason(res, run) -> str | None:
    """Why the fit ``res`` of ``run`` is restarted (:func:`solve`), or None."""
    opt = run.opt
    if not (run.all_known and opt.sigma and opt.weight_errors):
        return None
    if not res.converged:
        return "did not converge"
    # per channel, as the gate judges (its share of the degrees of freedom here)
    r, rows = res.residual, run.rows
    rss = np.bincount(run.row_channel, weights=r * r, minlength=len(run.channels))
    for ch, nc, rc in zip(run.channels, run.channel_count.tolist(), rss.tolist()):
        dof = nc - run.n_active * nc / rows
        chi2 = rc / float(run.known[ch]) ** 2
        if dof > 0.5 and special.chdtrc(dof, chi2) < RESTART_ALPHA:  # (False for NaN)
            return (f"ended at chi-square {chi2:.4g} on {dof:.4g} degrees of freedom at "
                    f"{ch}'s stated noise ({chi2 / dof:.3g} per degree)")
    return None


#: what may end a restart without ending the calibration: the first fit is kept
_RESTART_ERRORS = (CalibrationError, np.linalg.LinAlgError, ArithmeticError, ValueError)


def _restarted(model, opt, callback, t_start):
    """The restart of :func:`solve`: ``(result or None, why it failed or "")``, the
    fit on the other path (:class:`Algorithm2`)."""
    try:
        return _solve(model, opt, callback, t_start, other_path=True)[0], ""
    except _RESTART_ERRORS as e:
        return None, str(e) or type(e).__name__


def _solve(model, opt, callback, t_start, other_path=False):
    """One run of :func:`solve` (``other_path``: see :class:`Algorithm2`): ``(result,
    run)``."""
    run = Algorithm2(model, opt, callback, other_path)
    run.initial_status()
    converged, message = False, ""
    # (a pooled round the stated sigma follow with the same minimum runs to the end)
    early = run.can_reweight() and run.mode == "pooled" and not run.stated_uniform()
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
    return make_result(run, converged, message, t_start, rounds), run
