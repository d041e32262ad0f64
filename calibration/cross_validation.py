"""Cross-validation over the fit poses: how well a model predicts a pose the fit has not
seen (issue 42), from one fit.

Leaving a pose out and fitting again moves the solution by what the pose's rows pulled;
to first order the pose's error under that fit is its *deleted residual*
``(I - H_ii)^-1 r_i`` (:func:`calibration.pose_quality.pose_blocks`), so leave-one-pose-out
cross-validation costs one factorization, not one fit per pose. Two models of the same
poses (a rigid arm and a compliant one) are compared pose by pose:
:func:`compare_models` tests whether one predicts the poses it has not seen better,
with a signed-rank test, since real residuals are heavy-tailed (a pose of high leverage
has a deleted error many times its residual, and one such pose must not decide).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from calibration import pose_quality as pq
from calibration import quality as q

#: a model is preferred where the signed-rank test's one-sided p is below this
PREFER_P = 0.01
#: fewer poses in common than this and the test is not made
MIN_POSES = 6


def unseen_errors(r, W, weights, active, row_pose) -> dict[int, tuple[float, float, int]]:
    """Per fit pose (its position among the model's poses): ``(whitened squared size,
    squared size, rows)`` of its deleted residual, the pose's error predicted by the fit
    without it. Poses that alone determine a direction are left out (their error
    without them is not defined to first order)."""
    w = np.asarray(weights, dtype=float)
    U = q.hat_basis(W, w, np.asarray(active, bool))
    out = {}
    for b in pq.pose_blocks(r, U, w, row_pose):
        e = b.deleted
        out[b.pose] = (float(e @ (w[b.rows] * e)), float(e @ e), len(b.rows))
    return out


@dataclass(frozen=True)
class Comparison:
    """Model B against model A over the poses both predicted unseen: ``poses`` in
    common, ``wins`` where B's error was the smaller, the one-sided signed-rank ``p``
    that B predicts better (``p_worse``: that it predicts worse), each model's ``rms``
    of the unseen errors per row (residual units)."""

    poses: int
    wins: int
    p: float
    p_worse: float
    rms_a: float
    rms_b: float

    @property
    def better(self) -> bool:
        return self.poses >= MIN_POSES and self.p < PREFER_P

    @property
    def worse(self) -> bool:
        return self.poses >= MIN_POSES and self.p_worse < PREFER_P


def compare_models(a: dict, b: dict) -> Comparison | None:
    """:class:`Comparison` of the unseen errors ``b`` against ``a`` (each
    :func:`unseen_errors` keyed by a pose identity both share), None with fewer than
    :data:`MIN_POSES` poses in common."""
    from scipy.stats import wilcoxon

    keys = sorted(set(a) & set(b))
    if len(keys) < MIN_POSES:
        return None
    d = np.array([a[k][0] - b[k][0] for k in keys])
    rows = sum(a[k][2] for k in keys)
    rms_a = math.sqrt(sum(a[k][1] for k in keys) / rows)
    rms_b = math.sqrt(sum(b[k][1] for k in keys) / rows)
    if not np.any(d):
        return Comparison(len(keys), 0, 1.0, 1.0, rms_a, rms_b)
    p = float(wilcoxon(d, alternative="greater").pvalue)
    p_worse = float(wilcoxon(d, alternative="less").pvalue)
    return Comparison(len(keys), int(np.sum(d > 0)), p, p_worse, rms_a, rms_b)


def held_in_turn(r, W, weights, active, row_pose, shifts) -> dict[int, dict]:
    """Each active column ``j`` of ``shifts`` (``{j: start - estimate}``) held at its start
    in turn, the others refitted (linearized at the solution): the unseen errors of that
    model (:func:`unseen_errors`), keyed by ``j``. What a parameter buys the prediction
    of poses the fit has not seen: :func:`compare_models` of the full model's against
    these."""
    w = np.asarray(weights, dtype=float)
    sw = np.sqrt(w)
    active = np.asarray(active, bool)
    out = {}
    for j, shift in shifts.items():
        keep = active.copy()
        keep[j] = False
        rb = r + W[:, j] * shift
        A = W[:, keep]
        d = np.linalg.lstsq(A * sw[:, None], rb * sw, rcond=None)[0]
        out[j] = unseen_errors(rb - A @ d, W, w, keep, row_pose)
    return out
