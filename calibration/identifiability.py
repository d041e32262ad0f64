"""Identifiability of calibrated parameters by QR of the scaled observation
matrix, in parameter order (report section 5).

The columns of ``W`` are error-weighted (``G W``) and scaled to unit norm
(``H``), then factored ``W = Q R`` without pivoting, so that ``|R[j, j]|`` is the
distance of column j from the span of the columns before it. A parameter is

* identifiable where that distance is clearly non-zero;
* not identifiable, **no influence**, where its whole column is zero: the
  measurements do not depend on it, so leaving it at a wrong nominal value
  does not bias the others;
* not identifiable, **influences the model**, where its column is a
  combination of earlier ones: a wrong nominal value is absorbed by (biases)
  the others.

"Zero" has two parts. The numerical part is ``rank_tol`` relative to the
largest column. The statistical part applies at the solution only
(``residual`` given): several dependencies hold exactly only where the model
fits the data (the scale of a self-calibration, a plane absorbing a
translation); with noisy data those columns, or their independent parts, are
of the order of the residual. A column part no larger than ``kappa`` times the
weighted residual norm (SI units per parameter unit) carries no information
beyond the noise and is judged zero. In terms of the estimate this flags a
parameter whose standard deviation would exceed ``1/(kappa*sqrt(rows))`` in SI
units (rad, m, or the ratio itself for a transmission ratio).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

IDENTIFIABLE = "identifiable"
NO_INFLUENCE = "no influence"
INFLUENCES = "influences the model"


@dataclass(frozen=True)
class ParameterStatus:
    name: str
    identifiable: bool
    influences_model: bool  # meaningful where not identifiable
    r_diag: float  # |R[j, j]| of the scaled, weighted matrix (1 = independent)
    column_norm: float  # ||G W[:, j]|| (weighted, per parameter unit)

    @property
    def label(self) -> str:
        if self.identifiable:
            return IDENTIFIABLE
        return INFLUENCES if self.influences_model else NO_INFLUENCE


def analyze(W: np.ndarray, names, *, weights: np.ndarray | None = None,
            candidates: np.ndarray | None = None, residual: np.ndarray | None = None,
            rank_tol: float = 1e-8, kappa: float = 3.0) -> list[ParameterStatus]:
    """Classify every parameter (see module doc).

    W:          ``(rows, N)`` observation matrix.
    weights:    ``(rows,)`` error weights (the diagonal of L), default 1.
    candidates: ``(N,)`` bool, the parameters that may be calibrated at all
                (others are reported not identifiable, no influence, and do not
                enter the QR).
    residual:   ``(rows,)`` residual at the solution, enabling the statistical test.
    """
    W = np.asarray(W, dtype=float)
    rows, n = W.shape
    g = np.ones(rows) if weights is None else np.sqrt(np.asarray(weights, dtype=float))
    Wg = W * g[:, None]
    norms = np.linalg.norm(Wg, axis=0)
    cand = np.ones(n, bool) if candidates is None else np.asarray(candidates, bool)
    floor = rank_tol * (norms[cand].max() if cand.any() else 0.0)
    if residual is not None:
        floor = max(floor, kappa * float(np.linalg.norm(g * residual)))
    zero = norms <= floor
    use = cand & ~zero
    # QR in parameter order, column by column (Gram-Schmidt with
    # re-orthogonalisation): R[j, j] is the distance of column j from the span
    # of the earlier columns that were kept.
    basis = np.zeros((rows, 0))
    out = []
    for j in range(n):
        if not use[j]:
            out.append(ParameterStatus(names[j], False, False, 0.0, float(norms[j])))
            continue
        v = Wg[:, j] / norms[j]
        for _ in range(2):
            v = v - basis @ (basis.T @ v)
        rjj = float(np.linalg.norm(v))
        dep = rjj <= rank_tol or rjj * norms[j] <= floor
        if not dep:
            basis = np.column_stack([basis, v / rjj])
        out.append(ParameterStatus(names[j], not dep, dep, rjj, float(norms[j])))
    return out


def minimum_poses(n_identifiable: int, p: int) -> int:
    """Recommended pose count, eq. 60: ``m >= 5 N_R / p``."""
    return int(np.ceil(5 * n_identifiable / max(p, 1)))
