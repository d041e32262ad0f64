"""A pose's rows judged as one block (issue 42): every point a pose read, its deleted
residual (the pose's error from the fit made without it) with its leverage, and the
level real residuals show, where what the geometric model cannot describe sets them,
not the instrument (:func:`robust_level`). The gate's use of them is
:mod:`station.fitting.pose_outliers`; the row-wise tests are :mod:`calibration.quality`.
"""
from __future__ import annotations

import math
from array import array
from dataclasses import dataclass

import numpy as np
from scipy import special

from calibration.quality import MAX_LEVERAGE, OUTLIER_ALPHA, ROUNDOFF, _f_isf


@dataclass(frozen=True, slots=True)
class PoseBlock:
    """A pose's rows judged as one block (every point it read: issue 42). ``deleted`` is
    the deleted residual ``(I - H_ii)^-1 r_i``, the pose's error from the fit made
    without it (to first order; residual units); ``size`` its Mahalanobis size per row
    ``sqrt(r_i^T (I - H_ii)^-1 r_i / k)`` in the rows' residual units (whitened, times
    their sigma), the same whatever the pose's leverage for a reading of pure noise;
    ``t = sqrt(T^2)`` externally studentized (``T^2 / k ~ F(k, dof - k)``) against the
    noise-level ``threshold`` (Bonferroni over the poses tested) with its tail ``p``;
    ``leverage`` the largest eigenvalue of the pose's block ``H_ii`` of the hat matrix."""

    pose: int
    rows: np.ndarray
    deleted: np.ndarray
    size: float
    t: float
    threshold: float
    p: float
    leverage: float


def pose_blocks(r, U, weights, row_pose, *, alpha: float = OUTLIER_ALPHA) -> list[PoseBlock]:
    """Every testable pose's :class:`PoseBlock` at a solution: ``U`` the hat basis
    (:func:`hat_basis`) of the weighted, scaled identifiable columns, ``row_pose`` each
    row's pose (position among the fit's poses). Only the pose's block ``H_ii = U_i
    U_i^T`` of the hat matrix is formed. A pose is not testable where it alone
    determines a direction (``H_ii`` has an eigenvalue 1), where its residual is zero
    or too few degrees of freedom remain without it."""
    from scipy.special import fdtrc

    r = np.asarray(r, dtype=float)
    w = np.asarray(weights, dtype=float)
    rw = r * np.sqrt(w)
    rp = np.asarray(row_pose)
    dof = len(r) - float(np.einsum("ij,ij->", U, U))
    rss = float(rw @ rw)
    # the testable poses: their rows and deleted residuals, and (compactly: a motion
    # capture has 100 000 poses) pose, size, t^2, rows and leverage
    rows_of, deleted = [], []
    found = {"pose": array("q"), "size": array("d"), "t2": array("d"), "k": array("q"),
             "lev": array("d")}
    # each pose's rows (in row order, as flatnonzero(rp == i) has them): one sort
    order = np.argsort(rp, kind="stable")
    poses, starts = np.unique(rp[order], return_index=True)
    ends = np.r_[starts[1:], len(order)]
    for i, lo, hi in zip(poses.tolist(), starts.tolist(), ends.tolist()):
        rows = order[lo:hi]
        k = len(rows)
        H = U[rows] @ U[rows].T
        lev = float(np.linalg.eigvalsh(H).max()) if k else 0.0
        if lev >= MAX_LEVERAGE or dof - k <= 3 or np.linalg.norm(r[rows]) <= ROUNDOFF:
            continue
        ew = np.linalg.solve(np.eye(k) - H, rw[rows])
        qi = float(rw[rows] @ ew)
        s2 = max((rss - qi) / (dof - k), rss / dof * 1e-12 + 1e-300)
        rows_of.append(rows)
        deleted.append(ew / np.sqrt(w[rows]))
        for key, v in (("pose", int(i)), ("size", math.sqrt(max(qi, 0.0) /
                                                            float(np.sum(w[rows])))),
                       ("t2", max(qi, 0.0) / s2), ("k", k), ("lev", lev)):
            found[key].append(v)
    n = len(rows_of)
    threshold: dict[int, float] = {}  # (per block size: Bonferroni over the n poses)
    out = []
    for i, rows, e, size, t2, k, lev in zip(found["pose"], rows_of, deleted, found["size"],
                                            found["t2"], found["k"], found["lev"]):
        if k not in threshold:
            threshold[k] = math.sqrt(k * _f_isf(alpha / n, k, dof - k))
        out.append(PoseBlock(i, rows, e, size, math.sqrt(t2), threshold[k],
                             float(fdtrc(k, dof - k, t2 / k)), lev))
    return out


def _noise_log_upper(k: int) -> float:
    """The upper spread of ``log(chi_k)`` (:func:`robust_level`) where the residuals are
    the noise alone: its upper quartile above its median, in normal sigmas."""
    m, u = (0.5 * math.log(float(special.chdtri(k, p))) for p in (0.5, 0.25))
    return (u - m) / UPPER_QUARTILE


#: the upper quartile of the normal distribution, in sigmas
UPPER_QUARTILE = 0.6744897501960817


def robust_level(sizes, ks, *, alpha: float = OUTLIER_ALPHA) -> dict:
    """The poses' own scale (issue 42: real residuals, where what the geometric model
    cannot describe sets them, not the instrument), on a log scale: the median of the
    :attr:`PoseBlock.size` s and their upper spread, the median of the deviations above
    the median (the upper quartile) in normal sigmas (a pose that fits very well does
    not widen it); ``limit`` the size beyond which a pose stands out of the others
    (Bonferroni over the poses, normal on the log scale); ``spread`` the upper spread
    against the one noise alone gives (about 1 for residuals of pure noise)."""
    from scipy.special import ndtri

    ls = np.log(np.maximum(np.asarray(sizes, dtype=float), ROUNDOFF))
    med = float(np.median(ls))
    up = ls[ls > med] - med
    s_up = float(np.median(up)) / UPPER_QUARTILE if up.size else 0.0
    n = len(ls)
    z = float(-ndtri(alpha / max(n, 1)))
    k = int(np.median(ks)) if len(ks) else 3
    return {"median": math.exp(med), "limit": math.exp(med + z * s_up),
            "spread": s_up / _noise_log_upper(k), "poses": n}
