"""Cross-validation over the fit poses (:mod:`calibration.cross_validation`): each pose's
error as the fit without it predicts it, and two models compared pose by pose."""
from __future__ import annotations

import numpy as np
import pytest

from calibration import cross_validation as cv

N_POSE, K = 40, 6


def _problem(seed: int, extra: float):
    """A linear problem of poses of ``K`` rows: a base model of 4 columns and one extra
    column whose true effect is ``extra``; the noise heavy-tailed per pose."""
    rng = np.random.default_rng(seed)
    J = rng.normal(size=(N_POSE * K, 5))
    scale = np.repeat(np.exp(rng.normal(scale=0.5, size=N_POSE)), K)
    y = J[:, :4] @ rng.normal(size=4) + extra * J[:, 4] + rng.normal(size=len(scale)) * scale
    return J, y, np.repeat(np.arange(N_POSE), K)


def _unseen(J, y, rp, cols, weights=None):
    w = np.ones(len(y)) if weights is None else weights
    A = J[:, cols]
    sw = np.sqrt(w)
    x = np.linalg.lstsq(A * sw[:, None], y * sw, rcond=None)[0]
    return cv.unseen_errors(y - A @ x, A, w, np.ones(len(cols), bool), rp)


def test_unseen_errors_are_the_errors_of_the_fits_without_each_pose():
    J, y, rp = _problem(1, 0.5)
    w = np.where(np.arange(len(y)) % 2, 4.0, 1.0)        # two channels, two weights
    got = _unseen(J, y, rp, [0, 1, 2, 3, 4], w)
    assert sorted(got) == list(range(N_POSE))
    for i in (0, 7, 39):
        keep = rp != i
        sw = np.sqrt(w[keep])
        x = np.linalg.lstsq(J[keep] * sw[:, None], y[keep] * sw, rcond=None)[0]
        e = y[~keep] - J[~keep] @ x
        white, raw, rows = got[i]
        assert rows == K
        assert raw == pytest.approx(float(e @ e), rel=1e-9)
        assert white == pytest.approx(float(e @ (w[~keep] * e)), rel=1e-9)


def test_a_term_the_data_hold_is_preferred_and_one_they_do_not_is_not():
    J, y, rp = _problem(2, 1.0)
    c = cv.compare_models(_unseen(J, y, rp, [0, 1, 2, 3]), _unseen(J, y, rp, [0, 1, 2, 3, 4]))
    assert c.better and not c.worse and c.rms_b < c.rms_a and c.poses == N_POSE
    preferred = 0
    for seed in range(20):
        J, y, rp = _problem(100 + seed, 0.0)
        c = cv.compare_models(_unseen(J, y, rp, [0, 1, 2, 3]),
                              _unseen(J, y, rp, [0, 1, 2, 3, 4]))
        preferred += c.better
    assert preferred <= 2          # p < 0.01 each: about 0.2 of 20 expected


def test_too_few_poses_in_common_make_no_comparison():
    a = {i: (1.0, 1.0, 3) for i in range(10)}
    b = {i + 7: (0.5, 0.5, 3) for i in range(10)}
    assert cv.compare_models(a, b) is None
    same = cv.compare_models(a, dict(a))
    assert same is not None and not same.better and not same.worse


def test_each_column_held_in_turn_shows_what_it_buys():
    """Held at its start in turn: the column with a large true effect predicts the unseen
    poses much worse held; the one with none does not (held exactly, as it was fitted)."""
    J, y, rp = _problem(3, 0.0)
    y = y + 5.0 * J[:, 0]
    cols = np.ones(5, bool)
    x = np.linalg.lstsq(J, y, rcond=None)[0]
    r = y - J @ x
    w = np.ones(len(y))
    full = cv.unseen_errors(r, J, w, cols, rp)
    held = cv.held_in_turn(r, J, w, cols, rp, {0: -x[0], 4: -x[4]})
    assert cv.compare_models(full, held[0]).worse
    assert not cv.compare_models(full, held[4]).worse
