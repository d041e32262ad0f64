"""Fit-quality statistics at a solution: outlier tests, noise consistency, pose spread.

Pure numerics (no I/O); :mod:`station.fitting.batch` runs the gate with them.

* Outliers: externally studentized residuals from the hat matrix of the
  weighted, linearized problem at the solution. For a row ``i`` of channel
  ``c`` with leverage ``h_i``, ``t_i = r_i / (s_c(i) sqrt(1 - h_i))`` where
  ``s_c(i)`` is the channel's noise estimated without row ``i``
  (``(RSS_c - r_i^2 / (1 - h_i)) / (dof_c - 1)``, ``dof_c = n_c - sum h``).
  Under the model ``t_i`` follows Student's t with ``dof_c - 1`` degrees of
  freedom; the threshold is Bonferroni-corrected over every row tested, so a
  clean trace loses a pose with probability below :data:`OUTLIER_ALPHA`.
  Leaving the row out of the noise estimate keeps a gross reading from hiding
  itself by inflating the estimated sigma, and it does not trust a stated sigma
  (that is the consistency test's business).
* Held-out rows (not in the fit): the prediction error over its own std,
  ``t = e / (s_c sqrt(1 + h))`` with ``h = w J (A^T A)^+ J^T`` the fitted
  parameters' uncertainty at the row in units of its noise and ``s_c^2 =
  RSS_c / dof_c`` of the fit; Student's t with ``dof_c`` degrees of freedom,
  Bonferroni over the held-out rows. A fit row's externally studentized
  residual is this statistic for the row left out of the fit.
* Consistency: per channel with a stated sigma, ``RSS_c / sigma_c^2`` against
  chi-square with ``dof_c`` degrees of freedom (upper tail).
* Spread: the number of distinct poses (actuator values).

The hat matrix itself (leverages, its basis) is :mod:`calibration.hat_matrix`; a pose's
rows judged as one block and the level real residuals show, :mod:`calibration.pose_quality`;
the robust fit that names a gross reading where least squares does not converge,
:mod:`calibration.robust_fit`.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import special

from calibration.errors import CalibrationError
from calibration.hat_matrix import _scaled_svd, hat_basis, leverage, prediction_leverage  # noqa: F401 (q.leverage ...)

# Family-wise false-alarm probability of the outlier test on a clean trace.
OUTLIER_ALPHA = 1e-3
# Upper-tail probability below which residuals contradict the stated noise.
CHI2_ALPHA = 1e-3
# A residual below this (SI units) is round-off of a noise-free trace, not a reading.
ROUNDOFF = 1e-10
# Leverage above which a row cannot be tested (its residual is forced to ~0).
MAX_LEVERAGE = 1 - 1e-6


# The tails of Student's t and chi-square by the scipy.special functions that
# scipy.stats.t and scipy.stats.chi2 call (equal to the last bit for degrees of
# freedom > 0, tests/calibration/test_quality.py); scipy.stats costs every
# process about 0.5 s of imports.
def t_isf(q, df):
    """``scipy.stats.t.isf(q, df)``: the t value exceeded with probability ``q``."""
    return -special.stdtrit(df, q)


def t_logsf(t, df):
    """``scipy.stats.t.logsf(t, df)``: log of the probability of exceeding ``t``."""
    with np.errstate(divide="ignore"):
        return np.log(special.stdtr(df, -np.asarray(t, dtype=float)))


def chi2_sf(x, df):
    """``scipy.stats.chi2.sf(x, df)``: probability of exceeding ``x``."""
    return special.chdtrc(df, x)


@dataclass(frozen=True)
class Outlier:
    """The most significant row: its index, channel, residual, t and threshold."""

    row: int
    channel: str
    residual: float
    t: float
    threshold: float


def _group_rows(groups) -> tuple[np.ndarray, int]:
    """``(rows (G, k), k)``: the rows of each group (equal sizes, e.g. a point's x, y, z)."""
    g = np.asarray(groups)
    order = np.argsort(g, kind="stable")
    counts = np.bincount(g)
    k = int(counts.max())
    if np.any(counts != k):
        raise CalibrationError("row groups must all have the same number of rows")
    return order.reshape(-1, k), k


def _f_isf(q: float, k: int, dof: float) -> float:
    """The upper-``q`` point of the F distribution ``F(k, dof)``."""
    from scipy.special import fdtri

    return float(fdtri(k, dof, 1.0 - q))


def worst_group(r, U, weights, row_channel, channels, groups, *,
                alpha: float = OUTLIER_ALPHA) -> tuple[Outlier | None, int]:
    """:func:`worst_row` for groups of rows read together (a point's x, y, z: one
    reading). A group's externally studentized statistic ``T^2 = r_g^T (I - H_g)^-1
    r_g / s_(g)^2`` (``H_g`` its block of the weighted hat matrix ``U U^T``, ``s_(g)^2``
    the channel's noise without the group) gives ``T^2 / k ~ F(k, dof_c - k)``; it does
    not depend on how the group's rows are turned (an instrument's frame). Returns the
    most significant group beyond the Bonferroni threshold over the groups tested
    (``Outlier.row`` its first row, ``residual`` its norm, ``t = sqrt(T^2)`` against
    ``threshold``), and the number of groups tested."""
    from scipy.special import fdtrc

    r = np.asarray(r, dtype=float)
    rw = r * np.sqrt(weights)
    rc = np.asarray(row_channel)
    rows, k = _group_rows(groups)
    h = np.einsum("ij,ij->i", U, U)
    dof = channel_dof(rc, len(channels), h)
    rss = np.bincount(rc, weights=rw * rw, minlength=len(channels))
    Ug = U[rows]                                          # (G, k, rank)
    I_H = np.eye(k) - np.einsum("gir,gjr->gij", Ug, Ug)
    rg = rw[rows]
    ch = rc[rows[:, 0]]
    big = np.linalg.eigvalsh(np.eye(k) - I_H).max(axis=1) if len(rows) else np.zeros(0)
    ok = (big < MAX_LEVERAGE) & (np.linalg.norm(r[rows], axis=1) > ROUNDOFF)
    ok &= dof[ch] - k > 3
    n_test = int(ok.sum())
    if n_test == 0:
        return None, 0
    qg = np.zeros(len(rows))
    qg[ok] = np.einsum("gi,gi->g", rg[ok], np.linalg.solve(I_H[ok], rg[ok][..., None])[..., 0])
    s2 = (rss[ch] - qg) / np.maximum(dof[ch] - k, 1)
    s2 = np.maximum(s2, (rss[ch] / np.maximum(dof[ch], 1)) * 1e-12 + 1e-300)
    T2 = np.where(ok, qg / s2, 0.0)
    p = np.where(ok, fdtrc(k, np.maximum(dof[ch] - k, 1.0), T2 / k), 1.0)
    i = int(np.argmin(p))
    q_bonf = alpha / n_test
    if not p[i] < q_bonf:
        return None, n_test
    thr = math.sqrt(k * _f_isf(q_bonf, k, float(dof[ch[i]] - k)))
    row = int(rows[i, 0])
    return Outlier(row, channels[ch[i]], float(np.linalg.norm(r[rows[i]])),
                   float(math.sqrt(T2[i])), thr), n_test


def prediction_blocks(model, result, W_new, row_channel_new, groups_new):
    """For groups of rows not in the fit (held-out points): each group's prediction
    error covariance ``s_c^2 (I + B_g (A^T A)^+ B_g^T)`` (:func:`prediction_std` for
    the whole group), ``(G, k, k)``; the groups' rows ``(G, k)``; and ``dof_c``
    per group."""
    W, channels, active, w, s2, dof = _fit_noise(model, result)
    rc = np.asarray(row_channel_new, dtype=int)
    rows, k = _group_rows(groups_new)
    W_new = np.atleast_2d(np.asarray(W_new, dtype=float))
    w_new = row_weights(rc, channels, result.sigma)
    if np.any(active):
        norms, _, sv, Vt = _scaled_svd(W, w, active, basis=False)
        del W                          # the fit's Jacobian (a large fit's largest array)
        B = W_new[:, active] * np.sqrt(w_new)[:, None] / norms
        Z = ((B @ Vt.T) / sv)[rows]                          # (G, k, rank)
        Hn = np.einsum("gir,gjr->gij", Z, Z)
    else:
        Hn = np.zeros((len(rows), k, k))
    ch = rc[rows[:, 0]]
    # a group's rows share one channel: noise s2_c each, parameters' part s2_c Hn
    cov = s2[ch][:, None, None] * (np.eye(k) + Hn)
    return cov, rows, dof[ch]


def worst_prediction_group(e, cov, rows, dof, row_channel_new, channels, *,
                           alpha: float = OUTLIER_ALPHA) -> tuple[Outlier | None, int]:
    """:func:`worst_prediction` for groups: ``T^2 = e_g^T C_g^-1 e_g``, ``T^2 / k ~
    F(k, dof_c)``; the group with the smallest p-value if below ``alpha / groups
    tested``. ``Outlier.row`` is the group's first row, ``residual`` its error's norm,
    ``t = sqrt(T^2)``."""
    from scipy.special import fdtrc

    e = np.asarray(e, dtype=float)
    k = rows.shape[1]
    eg = e[rows]
    d = np.asarray(dof, dtype=float)
    ok = (d > 3) & np.all(np.isfinite(eg), axis=1)
    n_test = int(ok.sum())
    if n_test == 0:
        return None, 0
    T2 = np.zeros(len(rows))
    T2[ok] = np.einsum("gi,gi->g", eg[ok], np.linalg.solve(cov[ok], eg[ok][..., None])[..., 0])
    p = np.where(ok, fdtrc(k, np.where(ok, d, 4.0), T2 / k), 1.0)
    i = int(np.argmin(p))
    q_bonf = alpha / n_test
    if not p[i] < q_bonf:
        return None, n_test
    rc = np.asarray(row_channel_new)
    thr = math.sqrt(k * _f_isf(q_bonf, k, float(d[i])))
    return Outlier(int(rows[i, 0]), channels[rc[rows[i, 0]]], float(np.linalg.norm(eg[i])),
                   float(math.sqrt(T2[i])), thr), n_test


def row_weights(row_channel, channels, sigma: dict) -> np.ndarray:
    s = np.array([float(sigma.get(ch) or 1.0) for ch in channels])
    s = np.where(np.isfinite(s) & (s > 0), s, 1.0)
    return 1.0 / s[np.asarray(row_channel)] ** 2


def channel_dof(row_channel, n_channels: int, h: np.ndarray) -> np.ndarray:
    """Residual degrees of freedom per channel: ``n_c - sum of its leverages``."""
    rc = np.asarray(row_channel)
    n_c = np.bincount(rc, minlength=n_channels).astype(float)
    return n_c - np.bincount(rc, weights=h, minlength=n_channels)


def worst_row(r, h, row_channel, channels, *, testable=None,
              alpha: float = OUTLIER_ALPHA) -> tuple[Outlier | None, int]:
    """The row with the largest externally studentized residual, if it exceeds the
    Bonferroni threshold; and the number of rows tested."""
    r = np.asarray(r, dtype=float)
    rc = np.asarray(row_channel)
    dof = channel_dof(rc, len(channels), h)
    rss = np.bincount(rc, weights=r * r, minlength=len(channels))
    ok = (h < MAX_LEVERAGE) & (np.abs(r) > ROUNDOFF)
    if testable is not None:
        ok &= testable
    ok &= dof[rc] > 3          # too few degrees of freedom left to estimate the noise
    n_test = int(ok.sum())
    if n_test == 0:
        return None, 0
    one_h = np.where(ok, 1 - h, 1.0)
    s2 = (rss[rc] - r * r / one_h) / np.maximum(dof[rc] - 1, 1)
    s2 = np.maximum(s2, (rss[rc] / np.maximum(dof[rc], 1)) * 1e-12 + 1e-300)
    t = np.where(ok, np.abs(r) / np.sqrt(s2 * one_h), 0.0)
    i = int(np.argmax(t))
    thr = float(t_isf(alpha / (2 * n_test), dof[rc[i]] - 1))
    if not t[i] > thr:
        return None, n_test
    return Outlier(i, channels[rc[i]], float(r[i]), float(t[i]), thr), n_test


def channel_noise(r, h, row_channel, n_channels: int) -> tuple[np.ndarray, np.ndarray]:
    """Per channel of the fit: the noise variance estimate ``RSS_c / dof_c`` and
    ``dof_c`` (:func:`channel_dof`)."""
    r = np.asarray(r, dtype=float)
    rc = np.asarray(row_channel)
    dof = channel_dof(rc, n_channels, h)
    rss = np.bincount(rc, weights=r * r, minlength=n_channels)
    return rss / np.maximum(dof, 1e-300), dof


def _fit_noise(model, result):
    """What a prediction's std needs from the fit: ``(W, channels, active, weights,
    s2_c, dof_c)`` at its solution (:func:`channel_noise`)."""
    r, W = model.evaluate(result.x)
    channels = tuple(model.channels)
    active = np.array([s.identifiable for s in result.status])
    w = row_weights(model.row_channel, channels, result.sigma)
    s2, dof = channel_noise(r, leverage(W, w, active), model.row_channel, len(channels))
    return W, channels, active, w, s2, dof


def prediction_std(model, result, W_new, row_channel_new) -> tuple[np.ndarray, np.ndarray]:
    """For rows not in the fit of ``model`` (``result`` its solution; ``W_new`` their
    Jacobian in the fit's columns, ``row_channel_new`` indices into the fit's
    channels): the std of each row's prediction error, ``s_c sqrt(1 + h_new)``
    (the channel's noise estimated from the fit's residuals, :func:`channel_noise`,
    and the fitted parameters' uncertainty, :func:`prediction_leverage`), and its
    degrees of freedom ``dof_c``."""
    W, channels, active, w, s2, dof = _fit_noise(model, result)
    rc = np.asarray(row_channel_new, dtype=int)
    h_new = prediction_leverage(W, w, active, W_new, row_weights(rc, channels, result.sigma))
    return np.sqrt(s2[rc] * (1 + h_new)), dof[rc]


def worst_prediction(e, std, dof, row_channel_new, channels, *,
                     alpha: float = OUTLIER_ALPHA) -> tuple[Outlier | None, int]:
    """Rows not in the fit (held out): each row's prediction error ``e`` in its own
    std (:func:`prediction_std`), ``t = |e| / std``, follows Student's t with the
    channel's ``dof`` (the externally studentized residual of :func:`worst_row` is
    this statistic for a fit row left out of the fit). The row with the smallest
    p-value, if below the Bonferroni level ``alpha / rows tested`` (two-sided);
    and the number of rows tested (those with ``dof > 3``)."""
    e = np.asarray(e, dtype=float)
    rc = np.asarray(row_channel_new)
    d = np.asarray(dof, dtype=float)
    sd = np.asarray(std, dtype=float)
    ok = (d > 3) & np.isfinite(e) & np.isfinite(sd) & (sd > 0)
    n_test = int(ok.sum())
    if n_test == 0:
        return None, 0
    t = np.where(ok, np.abs(e) / np.where(ok, sd, 1.0), 0.0)
    logp = np.where(ok, t_logsf(t, np.where(ok, d, 4.0)), 0.0)
    i = int(np.argmin(logp))
    if not logp[i] < math.log(alpha / (2 * n_test)):
        return None, n_test
    thr = float(t_isf(alpha / (2 * n_test), d[i]))
    return Outlier(i, channels[rc[i]], float(e[i]), float(t[i]), thr), n_test


def chi_square(r, h, row_channel, channels, sigma_stated: dict,
               alpha: float = CHI2_ALPHA) -> list[dict]:
    """Per channel with a stated sigma: the residual against that noise."""
    r = np.asarray(r, dtype=float)
    rc = np.asarray(row_channel)
    dof = channel_dof(rc, len(channels), h)
    rss = np.bincount(rc, weights=r * r, minlength=len(channels))
    out = []
    for k, ch in enumerate(channels):
        s = sigma_stated.get(ch)
        if not s or dof[k] <= 0.5:
            continue
        x2 = float(rss[k] / s ** 2)
        p = float(chi2_sf(x2, dof[k]))
        out.append({"channel": ch, "stated_sigma": float(s),
                    "fitted_sigma": math.sqrt(rss[k] / dof[k]),
                    "ratio": math.sqrt(x2 / dof[k]), "chi2": x2, "dof": float(dof[k]),
                    "p": p, "ok": p >= alpha})
    return out


def distinct_poses(qm: np.ndarray) -> int:
    """Number of distinct rows of actuator values (to 1e-6 of the spread)."""
    qm = np.atleast_2d(np.asarray(qm, dtype=float))
    if qm.size == 0:
        return 0
    scale = max(float(np.max(np.abs(qm))), 1.0)
    return len(np.unique(np.round(qm / (scale * 1e-6)), axis=0))
