"""Fit-quality statistics (calibration.quality) on linear least squares, where the
distribution of the externally studentized residual is exact: the outlier test's
false-alarm rate must be its nominal alpha, and one gross reading must be found."""
import numpy as np

from calibration import quality as q


def _linear(rng, n=40, p=5, sigma=1e-3):
    A = rng.normal(size=(n, p))
    y = A @ rng.normal(size=p) + rng.normal(scale=sigma, size=n)
    return A, y


def _residual(A, y):
    x, *_ = np.linalg.lstsq(A, y, rcond=None)
    return y - A @ x


def test_false_alarm_rate_is_the_bonferroni_alpha():
    """2000 clean linear fits at alpha = 0.05 (family-wise): the rate of a row
    flagged is 0.05 at most (Bonferroni is conservative) and not far below."""
    rng = np.random.default_rng(1)
    alarms = 0
    trials = 2000
    rc = np.zeros(40, dtype=int)
    for _ in range(trials):
        A, y = _linear(rng)
        h = q.leverage(A, np.ones(len(y)), np.ones(A.shape[1], bool))
        worst, n_test = q.worst_row(_residual(A, y), h, rc, ("d",), alpha=0.05)
        assert n_test == 40
        alarms += worst is not None
    rate = alarms / trials
    assert 0.03 <= rate <= 0.06, rate


def test_one_gross_reading_is_found_among_two_channels():
    rng = np.random.default_rng(2)
    A, y = _linear(rng, n=60)
    rc = np.tile([0, 1], 30)
    y = y * np.where(rc == 1, 100.0, 1.0)       # channel 1 a hundred times noisier
    A = A * np.where(rc == 1, 100.0, 1.0)[:, None]
    y[17] += 2.0                                 # 20 sigma of channel 1 (0.1)
    w = np.where(rc == 1, 1e-4, 1.0)
    x, *_ = np.linalg.lstsq(A * np.sqrt(w)[:, None], y * np.sqrt(w), rcond=None)
    h = q.leverage(A, w, np.ones(A.shape[1], bool))
    worst, _ = q.worst_row(y - A @ x, h, rc, ("a", "b"))
    assert worst is not None and worst.row == 17 and worst.channel == "b"
    assert worst.t > worst.threshold


def test_leverage_sums_to_the_rank_and_round_off_is_not_tested():
    rng = np.random.default_rng(3)
    A, y = _linear(rng, n=20, p=4)
    A[:, 3] = A[:, 2]                            # rank 3
    h = q.leverage(A, np.ones(20), np.ones(4, bool))
    assert abs(h.sum() - 3) < 1e-9
    worst, n_test = q.worst_row(np.full(20, 1e-15), h, np.zeros(20, int), ("d",))
    assert worst is None and n_test == 0


def test_chi_square_against_the_stated_sigma():
    rng = np.random.default_rng(4)
    A, y = _linear(rng, n=200, p=3, sigma=1e-3)
    r = _residual(A, y)
    h = q.leverage(A, np.ones(200), np.ones(3, bool))
    rc = np.zeros(200, int)
    (ok,) = q.chi_square(r, h, rc, ("d",), {"d": 1e-3})
    (low,) = q.chi_square(r, h, rc, ("d",), {"d": 2e-4})
    assert ok["ok"] and 0.8 < ok["ratio"] < 1.2
    assert not low["ok"] and low["ratio"] > 4


def test_distinct_poses():
    qm = np.array([[1.0, 2.0], [1.0, 2.0], [1.0, 2.0 + 1e-9], [3.0, 4.0]])
    assert q.distinct_poses(qm) == 2
    assert q.distinct_poses(np.zeros((5, 4))) == 1


def test_prediction_leverage_is_the_prediction_variance_of_rows_not_in_the_fit():
    """``x (A^T A)^-1 x^T`` for new rows (weighted, columns of any scale); for a fit
    row left out, h / (1 - h) of its leverage in the fit with it."""
    rng = np.random.default_rng(4)
    A, _ = _linear(rng, n=30, p=4)
    A = A * np.array([1.0, 50.0, 1e-3, 7.0])
    w = rng.uniform(0.5, 2.0, size=30)
    active = np.ones(4, bool)
    new = rng.normal(size=(5, 4)) * np.array([1.0, 50.0, 1e-3, 7.0])
    w_new = rng.uniform(0.5, 2.0, size=5)
    N = (A * w[:, None]).T @ A
    want = w_new * np.einsum("ij,ji->i", new, np.linalg.solve(N, new.T))
    got = q.prediction_leverage(A, w, active, new, w_new)
    assert np.allclose(got, want, rtol=1e-9)
    h = q.leverage(A, w, active)
    out = q.prediction_leverage(np.delete(A, 7, 0), np.delete(w, 7), active, A[[7]], w[[7]])
    assert np.isclose(out[0], h[7] / (1 - h[7]), rtol=1e-9)


class _Fit:
    """A linear fit as the gate sees it: ``evaluate``, channels, row_channel and a
    result with ``x``, ``status`` and ``sigma``."""

    def __init__(self, A, y):
        self.A, self.y = A, y
        self.channels = ("d",)
        self.row_channel = np.zeros(len(y), dtype=int)
        x, *_ = np.linalg.lstsq(A, y, rcond=None)
        status = [type("S", (), {"identifiable": True})()] * A.shape[1]
        self.result = type("R", (), {"x": x, "status": status, "sigma": {"d": 1.0}})()

    def evaluate(self, x):
        return self.y - self.A @ x, self.A


def test_held_out_false_alarm_rate_is_the_bonferroni_alpha_with_extrapolated_rows():
    """Held-out rows, some far outside the fit's (an extrapolation: the parameters'
    uncertainty there is many times the noise): the family-wise rate of a row
    refused at alpha = 0.05 is 0.05 at most and not far below. Against the noise
    alone (no parameter uncertainty) the extrapolated rows would be refused far
    more often."""
    rng = np.random.default_rng(5)
    trials, alarms, naive = 2000, 0, 0
    for _ in range(trials):
        A = rng.normal(size=(25, 4))
        new = rng.normal(size=(6, 4)) * np.array([1, 1, 1, 1, 6, 6])[:, None]
        x_true = rng.normal(size=4)
        fit = _Fit(A, A @ x_true + rng.normal(scale=1e-3, size=25))
        e = new @ (x_true - fit.result.x) + rng.normal(scale=1e-3, size=6)
        std, dof = q.prediction_std(fit, fit.result, new, np.zeros(6, int))
        worst, n_test = q.worst_prediction(e, std, dof, np.zeros(6, int), ("d",), alpha=0.05)
        assert n_test == 6 and np.allclose(dof, 21)
        alarms += worst is not None
        s = np.sqrt(np.sum(fit.evaluate(fit.result.x)[0] ** 2) / 21)
        naive += q.worst_prediction(e, np.full(6, s), dof, np.zeros(6, int), ("d",),
                                    alpha=0.05)[0] is not None
    print(f"refused: {alarms / trials:.3f}; against the noise alone {naive / trials:.3f}")
    assert 0.02 <= alarms / trials <= 0.06, alarms / trials      # rows correlated: below alpha
    assert naive / trials > 0.2, naive / trials


def test_tails_equal_scipy_stats_to_the_last_bit():
    """The gate's t and chi-square tails (scipy.special: no scipy.stats import at
    start-up) give scipy.stats' numbers exactly: fractional degrees of freedom, far
    tails, zero and infinity included; so does the solver's homogeneity test."""
    from scipy import stats

    from calibration.solver import weighting

    df = np.array([0.6, 1.0, 2.5, 3.2, 7.0, 22.9, 140.0, 3300.0, 1e5])[:, None]
    x = np.r_[0.0, 1e-8, 0.3, 1.0, 2.7, 5.0, 12.0, 60.0, 400.0, 1e4, np.inf][None, :]
    p = np.array([1e-12, 1e-7, 1.4e-5, 1e-3, 0.05, 0.5, 0.9])[None, :]
    assert np.array_equal(q.chi2_sf(x, df), stats.chi2.sf(x, df))
    assert np.array_equal(q.t_logsf(x, df), stats.t.logsf(x, df))
    assert np.array_equal(q.t_isf(p, df), stats.t.isf(p, df))
    rss_dof = [(2.0e-6, 20.0), (3.1e-6, 22.5), (9.0e-6, 21.0)]
    for scale in (1.0, 1.5, 2.0, 3.0):
        pairs = [(r * (scale if k == 2 else 1.0), d) for k, (r, d) in enumerate(rss_dof)]
        got = weighting._homogeneous(pairs)
        nu = sum(d for _, d in pairs)
        sp = sum(r for r, _ in pairs) / nu
        t = nu * np.log(sp) - sum(d * np.log(r / d) for r, d in pairs)
        t /= 1 + (sum(1 / d for _, d in pairs) - 1 / nu) / 6
        assert got == (float(stats.chi2.sf(t, 2)) > weighting.HOMOGENEITY_ALPHA)
