"""The settings of Algorithm 2 (:class:`SolverOptions`)."""
from __future__ import annotations

from dataclasses import dataclass


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
                    at least ten times the damping, and about half as long at most
                    (Levenberg-Marquardt safeguard; the retry's length from the
                    parabola along the rejected step, as MINPACK's); the
                    damping relaxes back to lambda after accepted steps (by
                    the gain ratio once it swings, see
                    :meth:`calibration.solver.step.Stepping.iterate`). False
                    runs the report's plain Algorithm 2.
    hold_damping:   once the damping swings, keep it at or above the damping
                    last rejected for the rest of the round. False (default):
                    each step whose gain ratio is above ``GOOD_GAIN`` lowers
                    that floor threefold. True: a fit that may drift along a
                    valley away from its basin stays damped (the PM start fit,
                    :mod:`calibration.pm_start`).
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
    hold_damping: bool = False

