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

Modules: :mod:`~calibration.solver.options` (the settings),
:mod:`~calibration.solver.step` (the iteration, as the report writes
Algorithm 2: scale, classify, step, damp, stop), its speed-ups each in a module
named for what it saves (:mod:`~calibration.solver.factored`: the factorization
of the scaled system and its solves; :mod:`~calibration.solver.stopping`: the
predicted last step and the early switch; :mod:`~calibration.solver.retries`:
the damping's safeguard; :mod:`~calibration.solver.history`: the record formed
when read), :mod:`~calibration.solver.weighting` (sigma and L, eq. 51),
:mod:`~calibration.solver.rounds` (:func:`solve`: rounds and identifiability),
:mod:`~calibration.solver.result` (the result, final covariance and status).

Cost: one Householder QR of ``[G W_R H, G r]`` per iteration gives the step
for every damping tried there, the variance and (with the singular values of
its small triangle) the condition number; the final covariance and condition
number reuse a QR already made at the solution where the weights allow, and
so do the identifiability checks: at the start the first iteration's QR, at
the solution the last iteration's where both weightings are uniform, decide
wherever every parameter is clearly identifiable (else
:func:`calibration.identifiability.classify` does). The
per-channel weights of a multi-channel fit are fixed as soon as the pooled fit
predicts its solution's residual reliably (see :func:`solve`), not after
iterating the pooled fit to epsilon.
"""
from __future__ import annotations

from calibration.solver.history import Iteration
from calibration.solver.options import SolverOptions
from calibration.solver.result import CalibrationResult
from calibration.solver.rounds import solve
from calibration.solver.stopping import EARLY_SWITCH
from calibration.solver.weighting import SIGMA_CHANGE, SIGMA_FLOOR

__all__ = ["EARLY_SWITCH", "SIGMA_CHANGE", "SIGMA_FLOOR", "CalibrationResult", "Iteration",
           "SolverOptions", "solve"]
