"""The Levenberg-Marquardt safeguard of Algorithm 2's damping (``SolverOptions.adaptive``;
False runs the report's plain Algorithm 2 with a fixed lambda).

A step that raises the weighted cost is rejected and retried (:meth:`Safeguard._retried`)
with at least ten times the damping and at a damping whose step is at most about
half as long (0.55), as far along it as the parabola through the two costs and the
slope puts the least cost (no shorter than a tenth: MINPACK's trust-radius rule;
:func:`retry_damping`). Ten times alone lowered the cost of a first rejected
Gauss-Newton step by 13 % where lm's retry (and now ours, at the same point) lowers
it tenfold, and then swung into a curved valley (AGEBOT's arm as a robot file from
its nominal, sigma stated: 49 iterations and 56 evaluations against lm's 11; 8 and 9
now). An accepted step relaxes the damping tenfold (never below lambda). Where that
swings, i.e. two iterations in a row needed a rejected step first, the damping
tenfold down is rejected again and again (a curved valley: sm-distance at 100 poses
took 106 iterations and 210 evaluations): from then on, in this round, an accepted
step relaxes the damping by its gain ratio (:meth:`Safeguard._relaxed`), no lower
than the damping last rejected, a floor that each step the linear model predicted
well (gain ratio above GOOD_GAIN) lowers threefold: held for the rest of the round
it kept the damping far above the weak directions' singular values where the
rejection happened far from the solution (the same robot file: floor 666 against
s_min 50-150, 440 iterations); ``SolverOptions.hold_damping`` keeps it, as the PM
start fit needs: calibration.pm_start. The retry is never less damped than ten
times: a smaller rise keeps the steps towards the spurious minimum a Gauss-Newton
step can point at (sm-distance), and retrying at a fixed fraction of the length
alone (a trust region, where the damping is far above the weak singular values a
milder rise than tenfold) left the 6-9-pose planning refits of far-off arms
unconverged more often (a session's scout refit went from 2e-9 to 7e-2 of residual
and the far-off arm's session failed its gate; docs/methods.md).

What it saves: iterations and model evaluations where a step overshoots (the
parabolic retry and the gain-ratio relaxation), and a false convergence where
only the damping made the step small (:meth:`Safeguard._stalled`). The step
lengths come from the iteration's factorization
(:class:`~calibration.solver.factored.Scaled`): no further QR.
"""
from __future__ import annotations

import math

import numpy as np

#: an accepted step whose gain ratio (actual over predicted decrease) is above
#: this lowers the floor the damping is held at, the damping last rejected,
#: threefold (:meth:`~calibration.solver.step.Stepping.iterate`)
GOOD_GAIN = 0.75
#: after rejected steps, a Gauss-Newton step still predicting a decrease of the
#: cost of more than this (chi-square units, i.e. a step of ~0.1 std) is not convergence
STALL_CHI2 = 1e-2
#: a rejected step is retried no longer than this fraction of it (10 % more at
#: most: :func:`damping_for`), nor shorter than ``RETRY_SHORTEST`` of it
#: (within those, where the cost along the step is least on the parabola through
#: the two costs and the slope; MINPACK's lmder)
RETRY_LONGEST, RETRY_SHORTEST = 0.5, 0.1


def damping_for(F, length: float, lam2: float) -> float:
    """The ``lambda^2``, not below ``lam2``, whose damped step is at most 10 %
    longer than ``length`` (scaled) and, if ``lam2``'s is longer, no shorter:
    Newton's method on ``1/||z(lambda^2)||``, increasing and concave in
    ``lambda^2``, from ``lam2`` (below the root: it converges from there
    without overshooting; Moré 1978, as MINPACK's lmpar). From the SVD of
    ``R`` (``A``'s singular values, ``c`` in their basis), n x n."""
    if F.svd is None:
        U, sv, _ = np.linalg.svd(F.R)
        c = U.T @ F.Rc[:, F.n]
    else:
        sv, c = F.sv, F.svd[1]
    s0 = float(sv[0])
    if not s0 > 0:
        return lam2
    keep = sv > s0 * 1e-15  # (the pseudo-inverse's cut, as :meth:`Scaled.step`)
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


def retry_damping(F, z, lam2: float, cost: float, cost_try: float) -> float:
    """The ``lambda^2`` at which to retry the rejected step ``z`` (made at
    ``lam2``; the cost ``cost`` here, ``cost_try`` there): its step between
    :data:`RETRY_SHORTEST` and :data:`RETRY_LONGEST` as long as ``z`` (within
    10 % above: :func:`damping_for`), where the parabola through the two costs
    and the slope here has its minimum along ``z`` (MINPACK's rule for its
    trust radius)."""
    slope = F.slope(z)
    rise = cost_try - cost + slope  # > slope: the cost rose, or fell less than predicted
    t = 0.5 * slope / rise if slope > 0 and rise > 0 else RETRY_SHORTEST
    t = min(max(t, RETRY_SHORTEST), RETRY_LONGEST)
    return damping_for(F, t * math.sqrt(float(z @ z)), lam2)


class Safeguard:
    """The damping's safeguard (mixin of :class:`calibration.solver.step.Stepping`)."""

    def _retried(self, F, z, lam2, cost, cost_try) -> float:
        """The damping at which to retry the rejected step ``z`` (made at ``lam2``;
        the cost ``cost`` here, ``cost_try`` there, None where the model could not
        be evaluated there): ten times this one at least, and where the step is at
        least as short as the parabola along it says."""
        lam_new = max(10 * self.lam_eff, 1e-3 * F.s0)
        if cost_try is not None:  # and at least as short as the parabola along it says
            lam_new = max(lam_new, math.sqrt(retry_damping(F, z, lam2, cost,
                                                           cost_try)))
        return lam_new

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
        (see the module's docstring), by its gain ratio ``rho`` (actual over predicted
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

