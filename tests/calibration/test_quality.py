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
