"""Error weighting of Algorithm 2: the sigma of one row per channel (eq. 51)
and the weights ``L = Sigma^-1`` (eq. 48), pooled over all rows (the report's
single sigma), known from the trace, or per channel.

:class:`Weighting` is a mixin of :class:`calibration.solver.rounds.Algorithm2`
and works on that run's state (``channels``, ``row_channel``, ``known``,
``sigma``, ``mode``, ``g``, ...; see there).
"""
from __future__ import annotations

import math

import numpy as np
from scipy import special
from scipy.linalg import lapack

from calibration import rowblocks

geqrf, orgqr = lapack.dgeqrf, lapack.dorgqr

# The smallest sigma an estimate takes (the residual's SI units; a zero one would
# weigh its rows infinitely).
SIGMA_FLOOR = 1e-14
# A material change of a channel's sigma between rounds (relative).
SIGMA_CHANGE = 0.05
# Every channel's sigma below this (SI units: 0.1 nm, 0.1 nrad, four orders of
# magnitude below the finest instrument) means the model matches the readings to
# round-off (noise-free data): weights per channel would only reweight round-off
# (a channel's sigma of 1e-13 m next to another's 1e-14 m), so no round is run
# for them; and where no channel's sigma is given and every channel's residual sum
# of squares is below its square, the channels share one sigma, with no degrees of
# freedom (:meth:`Weighting.channel_sigma`).
ROUNDOFF_SIGMA = 1e-10


class Weighting:
    """Sigma and weights (mixin of :class:`calibration.solver.rounds.Algorithm2`)."""

    def channel_sigma(self, r, n_active):
        """Sigma of one row per channel (eq. 51): known values where given; else
        estimated from the residual per channel with its share of the degrees of
        freedom (the pooled sigma of the first round: :meth:`_pooled_sigma`)."""
        n = len(r)
        memo = self._sigma_memo
        if memo[0] is r and memo[1] == n_active:
            self.sigma_dof = dict(memo[3])
            return dict(memo[2])
        rss = np.bincount(self.row_channel, weights=r * r, minlength=len(self.channels)).tolist()
        if not self.known and max(rss) <= ROUNDOFF_SIGMA ** 2:
            # the model matches every reading to round-off: the residual says
            # nothing of the noise (per-channel estimates would differ by the
            # round-off of each channel's arithmetic): one sigma for all, eq. 51
            # over all rows, and no degrees of freedom (it estimates no noise,
            # so it adds no uncertainty of its own to the covariance)
            out, dofs = self._pooled_sigma(float(sum(rss)), n, n_active), {}
        else:
            out, dofs = self._estimated_sigma(rss, n, n_active)
        self._sigma_memo = (r, n_active, out, dofs)
        self.sigma_dof = dict(dofs)
        return dict(out)

    def _estimated_sigma(self, rss, n, n_active):
        """``(sigma, dof)`` per channel from its residual sum of squares ``rss``
        (:meth:`channel_sigma`)."""
        known = self.known
        # the leverage (a QR of the whole matrix) only serves the channels estimated here
        used = ([None] * len(self.channels) if all(ch in known for ch in self.channels)
                else self._channel_leverage(n_active))
        out = {}
        est = {}  # channel -> (rss, dof) of the channels estimated here
        for ch, nc, rc, hc in zip(self.channels, self.channel_count.tolist(), rss, used):
            if ch in known:
                out[ch] = float(known[ch])
                continue
            dof = nc - (n_active * nc / n if hc is None else hc)
            out[ch] = max(math.sqrt(rc / dof) if dof > 0 else math.sqrt(rc / max(nc, 1)),
                          SIGMA_FLOOR)
            est[ch] = (rc, dof)
        dofs = {ch: d for ch, (_, d) in est.items()}
        if len(est) > 1 and (self.sigma_shared or min(dofs.values()) < CHANNEL_MIN_DOF):
            # a channel whose rows the fit spends (nearly) all of: its residual
            # is round-off over round-off and says nothing of its noise (a
            # 6-pose start fit of sm-distance-tilt: the distance's 1.2e-6 m in
            # one run, 1.6e-12 m in another, its noise 1e-5 m; the fit then
            # went elsewhere): every estimated channel shares one sigma, as in
            # the pooled round, for the rest of the fit (at the weights that
            # sharing gives, the channel's leverage falls and its own estimate
            # would return, and the weights alternate round after round). The
            # channels estimated with less than one degree of freedom keep
            # their own count (the covariance credits them :data:`MIN_DOF`):
            # the shared sigma is the other channels' noise, not theirs.
            s, dof_all = _one_sigma(est.values())
            if s is not None:
                self.sigma_shared = True
                out.update(dict.fromkeys(est, s))
                dofs = {ch: d if d < CHANNEL_MIN_DOF else dof_all for ch, d in dofs.items()}
                return out, dofs
        for group in getattr(self.model, "noise_groups", ()):
            sub = {ch: est[ch] for ch in group if ch in est}
            if len(sub) > 1 and _homogeneous(sub.values()):
                # components of one sensor's reading whose noise levels the data
                # cannot tell apart: one sigma from all their rows is far surer
                # than each component's own, and weights that follow the scatter
                # of those would cost more than they win
                s, dof_all = _one_sigma(sub.values())
                out.update(dict.fromkeys(sub, s))
                dofs.update(dict.fromkeys(sub, dof_all))
        return out, dofs

    def covariance_sigma(self, sigma):
        """The sigma the covariance (eq. 52) is made with: a known sigma as given; an
        estimated one (``nu`` degrees of freedom, :attr:`sigma_dof`) times
        ``sqrt(nu / (nu - 2))``. Eq. 51's sigma is itself uncertain: with it in
        eq. 52, error / std follows Student's t with ``nu`` degrees of freedom,
        whose RMS is that factor (1.03 for 35 degrees of freedom, 1.07 for 15), so
        the std would be optimistic by as much. ``nu`` is taken as at least
        :data:`MIN_DOF`."""
        dof = getattr(self, "sigma_dof", {})
        return {ch: v * t_inflation(dof[ch]) if ch in dof and ch not in self.known else v
                for ch, v in sigma.items()}

    def _channel_leverage(self, n_active):
        """Degrees of freedom each channel spends on the fit: the sum of the
        leverages (diagonal of the weighted hat matrix ``A (A^T A)^-1 A^T``,
        ``A = G W_R``) over its rows, at the current weights. They add up to the
        number of calibrated parameters, but not in proportion to the rows: a
        precise channel fixes most parameters and spends most of them, and
        dividing its residual by its share of the rows instead would make its
        sigma, and with it the reported std, optimistic. ``[None, ...]`` for
        one channel (where the share is exact) or a matrix that is not tall."""
        nch = len(self.channels)
        W = self.W
        if nch < 2 or not n_active or W.shape[0] <= n_active:
            return [None] * nch
        cols = None if self.all_active else self.active_idx
        if len(rowblocks.spans(W.shape[0], n_active)) > 1:
            h = _leverage_by_blocks(W, cols, self.g)
            if h is None:
                return [None] * nch
            return np.bincount(self.row_channel, weights=h, minlength=nch).tolist()
        A = W if self.all_active else W.take(self.active_idx, axis=1)
        g = self.g
        A = A * g if isinstance(g, float) else A * g[:, None]
        norms = np.sqrt(np.einsum("ij,ij->j", A, A))
        if not norms.min() > 0:  # (also where NaN)
            return [None] * nch
        qr, tau, _work, info = geqrf(np.divide(A, norms, out=np.empty(A.shape, order="F")))
        # Q in C order, as np.linalg.qr gives it (the row sums below then add
        # up in the same order)
        Q = (np.ascontiguousarray(orgqr(qr[:, :n_active], tau)[0]) if info == 0
             else np.linalg.qr(A / norms)[0])
        h = np.einsum("ij,ij->i", Q, Q)
        return np.bincount(self.row_channel, weights=h, minlength=nch).tolist()

    def _pooled_sigma(self, rss, n, n_active):
        dof = n - n_active
        s = math.sqrt(rss / dof) if dof > 0 else math.sqrt(rss / n)
        return dict.fromkeys(self.channels, max(s, SIGMA_FLOOR))

    def row_weights(self, sigma):
        """The diagonal of L = Sigma^-1 for ``sigma`` (channel -> sigma)."""
        s = np.array([sigma[ch] for ch in self.channels])[self.row_channel]
        return 1.0 / (s * s)

    def _set_weights(self):
        """``self.g = sqrt(L)``: a float where every row has the same weight
        (L = I, or the pooled sigma), else per row."""
        if not self.opt.weight_errors:
            self.g = 1.0
        elif self.mode == "pooled":
            self.g = 1.0 / float(self.sigma[self.channels[0]])
        elif self._g_sigma is not self.sigma:
            self.g = self.sqrt_weights(self.sigma)
            self._g_sigma = self.sigma

    def sqrt_weights(self, sigma):
        """``sqrt(L)`` for ``sigma`` (channel -> sigma): a float where every channel's
        sigma is the same (one channel), else per row."""
        vals = [sigma[ch] for ch in self.channels]
        if all(v == vals[0] for v in vals):  # one sigma for every row (one channel)
            return 1.0 / float(vals[0])
        return (1.0 / np.array(vals, dtype=float))[self.row_channel]

    def _sigma_changed(self, sigma, old) -> bool:
        exact = all(v <= ROUNDOFF_SIGMA for v in sigma.values())
        return not exact and any(abs(sigma[ch] / old[ch] - 1) > SIGMA_CHANGE for ch in sigma)

    def can_reweight(self) -> bool:
        if self.mode == "known" or not self.opt.weight_errors:
            return False
        # every sigma stated: the pooled round is followed by the stated weights
        return self.all_known or len(self.channels) > 1

    def stated_uniform(self) -> bool:
        """Every sigma stated, and the same for every channel: the stated weights
        are the pooled round's times a constant (the same minimum)."""
        return self.all_known and len(set(self.known.values())) == 1

    def channels_differ(self) -> bool:
        """Would :meth:`reweight` change the weights materially now?"""
        if self.all_known:
            return self.can_reweight() and not self.stated_uniform()
        return self.can_reweight() and self._sigma_changed(
            self.channel_sigma(self.r_sol, self.n_active), self.sigma)

    def reweight(self) -> bool:
        """Per-channel weights at the solution; True if they changed materially
        (a new round is needed). Where every sigma is stated: the stated weights
        from here on, and a new round only where they weigh the channels otherwise
        than the pooled round's one sigma did."""
        if not self.can_reweight():
            return False
        if self.all_known:
            self.sigma, self.mode = dict(self.known), "known"
            self.next_factor = None  # made with the pooled weights
            self._set_weights()
            return not self.stated_uniform()
        sigma = self.channel_sigma(self.r_sol, self.n_active)
        old = self.sigma
        self.sigma, self.mode = sigma, "channel"
        self.next_factor = None  # made with the old weights
        self._set_weights()
        return self._sigma_changed(sigma, old)


def _one_sigma(rss_dof) -> tuple[float | None, float]:
    """One sigma (eq. 51) for several channels' rows, from each channel's residual
    sum of squares and degrees of freedom: ``(sigma, total dof)``; sigma None where
    they leave no degrees of freedom."""
    rss_dof = list(rss_dof)
    dof = sum(d for _, d in rss_dof)
    if not dof > 0:
        return None, dof
    return max(math.sqrt(sum(rc for rc, _ in rss_dof) / dof), SIGMA_FLOOR), dof


# Fewest degrees of freedom a channel's own sigma is estimated with; below, every
# estimated channel shares one sigma (:meth:`Weighting._estimated_sigma`).
CHANNEL_MIN_DOF = 1.0


# Fewest degrees of freedom credited to an estimated sigma (eq. 51) when its
# uncertainty is added to the std (:meth:`Weighting.covariance_sigma`): with 2 or
# fewer the t distribution has no variance; such a fit is refused by the station's
# quality gate as too few poses anyway.
MIN_DOF = 3.0


def t_inflation(dof: float) -> float:
    """``sqrt(nu / (nu - 2))``, the RMS of Student's t with ``nu = max(dof, MIN_DOF)``
    degrees of freedom: what an estimated sigma's own uncertainty adds to the std."""
    nu = max(float(dof), MIN_DOF)
    return math.sqrt(nu / (nu - 2.0))


# Significance of Bartlett's test below which the channels' noise levels are
# taken to differ (and each channel gets its own weight).
HOMOGENEITY_ALPHA = 0.01


def _homogeneous(rss_dof) -> bool:
    """Bartlett's test of equal variances from each channel's residual sum of
    squares and degrees of freedom: True where equal noise is not rejected at
    :data:`HOMOGENEITY_ALPHA`."""
    rd = [(rc, d) for rc, d in rss_dof if d > 0.5 and rc > 0]
    k = len(rd)
    if k < 2:
        return False
    nu = sum(d for _, d in rd)
    sp = sum(rc for rc, _ in rd) / nu
    t = nu * math.log(sp) - sum(d * math.log(rc / d) for rc, d in rd)
    t /= 1 + (sum(1 / d for _, d in rd) - 1 / nu) / (3 * (k - 1))
    return float(special.chdtrc(k - 1, t)) > HOMOGENEITY_ALPHA  # chi2.sf(t, k - 1)


def _leverage_by_blocks(W, cols, g):
    """The diagonal of the hat matrix of ``A = G W[:, cols]`` (``g``: a float, or one per
    row) a block of rows at a time: ``Q = A D R^-1`` (``D`` the unit columns' scaling,
    ``R`` the triangle of their QR, :mod:`calibration.rowblocks`), its rows' squared
    norms; None where a column is zero or the triangle singular."""
    rows = W.shape[0]
    n = W.shape[1] if cols is None else len(cols)
    norms = rowblocks.column_norms(W, cols, g)
    if not norms.min() > 0:  # (also where NaN)
        return None
    blocks = rowblocks.spans(rows, n)

    def unit(lo, hi):
        return np.divide(rowblocks.scaled_rows(W, lo, hi, cols, g), norms,
                         out=np.empty((hi - lo, n), order="F"))

    Rinv, info = lapack.dtrtri(rowblocks.triangle(unit, blocks, n))
    if info != 0:
        return None
    h = np.empty(rows)
    for lo, hi in blocks:
        Q = unit(lo, hi) @ Rinv
        h[lo:hi] = np.einsum("ij,ij->i", Q, Q)
    return h
