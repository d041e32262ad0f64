"""The stopping rules of Algorithm 2 beyond its own (``max |d_R| < epsilon``, or the
iteration limit, in :meth:`calibration.solver.step.Stepping.iterate`).

- The predicted last step (:meth:`Stopping._predicted_last`): where the steps
  contract fast (:meth:`Stopping._settles`), or the fit is exact and the next step
  is bounded from this one's linearization error (:func:`next_step_bound`), the
  step after this one is predicted below epsilon: this one is taken without
  evaluating the model there; the next round evaluates it first
  (:meth:`Stopping._evaluate_settled`). Saves the last model evaluation (and its
  factorization) of a converging round.
- The early switch of the pooled round (:meth:`Stopping._switch_early`,
  :data:`EARLY_SWITCH`): a multi-channel fit's pooled round stops before its step
  once the residual the step's linearization predicts is reliable; the per-channel
  weights are fixed from that prediction. Saves the pooled round's iterations to
  epsilon, a solution the per-channel round moves by O(std) anyway.
"""
from __future__ import annotations

import math

import numpy as np

from calibration.errors import CalibrationError
from calibration.solver.factored import ROUNDOFF_DAMPING, row_norms2

# Early switch to per-channel weights (see :func:`calibration.solver.rounds.solve`). The pooled round of a
# multi-channel problem stops before its step once the residual it predicts at
# its solution is reliable: the linearization's error, estimated from the last
# step's (which shrinks with the square of the step), is at most this fraction
# of every channel's predicted residual norm. The channel sigmas estimated from
# that prediction then differ from those at the pooled optimum by no more than
# this fraction (in practice far less), well inside the 5 % that decides
# whether a per-channel round is needed at all.
EARLY_SWITCH = 1e-2
#: a step is taken without evaluating the model after it (the iteration ends
#: there, :meth:`~calibration.solver.step.Stepping.iterate`) where the steps shrink at least this fast
#: (each at most this fraction of the one before) and the step after it is
#: predicted below epsilon
SETTLED_CONTRACTION = 0.1
#: the largest step (parameter units) whose linearization error is kept for that
#: bound
LINEARIZATION_WATCH = 1e-2
#: the residual (2-norm, SI units) below which a fit is exact (noise-free): the
#: convergence is then quadratic and the step after a step is bounded from that
#: step's linearization error (:func:`next_step_bound`); the
#: exact-fit limit of :mod:`calibration.solver.weighting`
EXACT_RESIDUAL = 1e-10
#: that bound must be below this fraction of epsilon: the error read off the last
#: step scales with the square of the step but changes direction (up to sixfold
#: under on sm-distance-tilt noise-free, 17 poses, seed 5)
EXACT_MARGIN = 0.1


def next_step_bound(F, err) -> float:
    """In a fit with no residual left after a step whose linearization error
    has the (weighted, ``g e``) norm ``err``: a bound on the largest parameter
    change of the Gauss-Newton step from there, ``h R^-1 Q^T g e``: component
    ``i`` at most ``h_i ||row i of R^-1|| ||g e||``. Infinite without ``R^-1``."""
    Rinv = F.Rinv
    if Rinv is None:
        return math.inf
    return math.sqrt(float(np.max(F.h * F.h * row_norms2(Rinv)))) * err


def held_back(F, z, lam2: float) -> float:
    """The largest parameter change of the part of the Gauss-Newton step that
    the damping ``lam2`` held back from the step ``z`` (it comes back in the
    next step); 0 where the damping is below round-off
    (:meth:`~calibration.solver.factored.Scaled.step`)."""
    if not lam2 * F.rinv2 > ROUNDOFF_DAMPING:
        return 0.0
    return float(np.max(np.abs(F.h * (F.step(0.0) - z))))


class Stopping:
    """The stopping rules (mixin of :class:`calibration.solver.step.Stepping`)."""

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

    def _switch_early(self, F, z, zn, lam2, r_lin, pred) -> bool:
        """May the pooled round stop before the step ``z`` (``zn = ||z||``, made at
        ``lam2``; ``r_lin`` the residual it predicts; ``pred``: (predicted residual
        after the last step, its ``||z||``, ``||actual - predicted||``) or None)? Where
        the error of the predicted residual is at most :data:`EARLY_SWITCH` of every
        channel's."""
        if not (pred is not None and pred[1] > 0):
            return False
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
        return err <= limit

    def _predicted_last(self, F, z, lam2, step, taken, eps, r_lin, lin_err) -> bool:
        """Is the step after ``z`` (largest change ``step``; made at ``lam2``,
        ``r_lin`` the residual it predicts, ``lin_err`` the last step's
        linearization error) predicted below ``eps``? Then ``z`` is the last step."""
        held = held_back(F, z, lam2)
        settle = self._settles(step, taken, eps, held)
        if (not settle and lin_err is not None
                and float(r_lin @ r_lin) <= EXACT_RESIDUAL ** 2):
            # an exact fit: the linearization error after this step, from
            # the last step's (second order: as the square of the scaled
            # steps), bounds the step after it
            e_prev, zn2_prev = lin_err
            ge = F.g * e_prev
            err = math.sqrt(float(ge @ ge)) * float(z @ z) / zn2_prev
            settle = next_step_bound(F, err) + held < EXACT_MARGIN * eps
        return settle

    def _evaluate_settled(self) -> str:
        """Evaluate the model at the last step, taken without evaluating it (the
        last round ended there): "" or why it cannot be."""
        self.settled = False
        released = self._let_go()
        try:
            self.r, self.W = self.evaluate(self.x)
            self.W_key, self.W_at = object(), self.x
        except CalibrationError as e:
            if released:  # (the matrix of the point before, as it was)
                self.W = self.model.evaluate(self.W_at)[1]
            return f"the model cannot be evaluated at the solution ({e})"
        self.next_factor = None
        self._reweighed()
        return ""
