"""A calibration method is a measurement model (house style 4).

A measurement model knows, for one data set and one kinematic model, how to
predict the measured quantities from the calibrated parameters ``x`` and how
those predictions change with ``x``:

* ``evaluate(x) -> (r, W)``: the residual ``r = measured - predicted`` (the
  report's ``Delta X_ag``, shape ``(rows,)``) and the observation matrix
  ``W = d predicted / d x`` (shape ``(rows, N)``), so that ``r ~ W dx`` (eq. 28).
* ``row_channel``: the channel each row belongs to (index into ``channels``),
  for the per-channel error weighting L and the per-channel sigma.

One solver (:mod:`calibration.solver`) runs Algorithm 2 on any of them.
"""
from __future__ import annotations

import numpy as np

from calibration.errors import CalibrationError


class MeasurementModel:
    """Base class of every calibration method.

    Subclasses set in ``__init__``: ``names`` (parameter names), ``x0`` (start
    values: the nominal, possibly re-estimated), ``nominal`` (the nominal as
    given), ``channels``, ``row_channel`` and ``n_poses``; and implement
    :meth:`evaluate`.
    """

    method: str = ""
    names: tuple[str, ...]
    x0: np.ndarray
    nominal: np.ndarray
    channels: tuple[str, ...]
    row_channel: np.ndarray
    n_poses: int
    default_damping: float = 1e-4
    # groups of channels that are components of one sensor's reading (the solver
    # gives them one sigma where the data cannot tell their noise levels apart)
    noise_groups: tuple[tuple[str, ...], ...] = ()
    notes: tuple[str, ...] = ()
    # the order in which the identifiability analysis judges the parameters (indices
    # into ``names``; None: their own order). Of dependent parameters the one judged
    # first is calibrated: a method whose instrument frame and tool are unknown
    # judges them first, so that what they absorb is theirs, not the robot's.
    identify_order: np.ndarray | None = None
    # can :meth:`evaluate` be called at any finite parameters without failing (no
    # assembly, no domain)? Then the solver may end a round on a step it predicts
    # and has not evaluated (:meth:`calibration.solver.step.Stepping.iterate`);
    # a model that can fail somewhere (a PM that cannot assemble) is evaluated at
    # every point the solver reports.
    evaluates_everywhere: bool = False

    @property
    def n_params(self) -> int:
        return len(self.names)

    @property
    def p(self) -> int:
        """Rows per pose (the report's p)."""
        return len(self.row_channel) // max(self.n_poses, 1)

    def evaluate(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:  # pragma: no cover
        raise NotImplementedError

    def residuals(self, x: np.ndarray) -> np.ndarray:
        return self.evaluate(x)[0]

    def jacobian(self, x: np.ndarray) -> np.ndarray:
        return self.evaluate(x)[1]

    def consistent_twin(self, x: np.ndarray) -> "MeasurementModel":
        """The same method on data that the parameters ``x`` explain exactly.

        The solver judges structural identifiability on it before iterating.
        Where the readings enter only the residual (reading minus prediction),
        ``W`` does not depend on them and the model is its own twin. Methods
        whose rows are constraints among predictions (self-calibration, a
        plane) move their poses so that ``x`` satisfies the constraints."""
        return self



def require_finite(name: str, a: np.ndarray) -> np.ndarray:
    a = np.asarray(a, dtype=float)
    if not np.all(np.isfinite(a)):
        bad = np.argwhere(~np.isfinite(a))[0]
        raise CalibrationError(f"{name} has a non-finite value at pose {int(bad[0])}")
    return a
