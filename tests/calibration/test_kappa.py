"""The statistical identifiability threshold kappa (calibration.identifiability):
a column part no larger than kappa = 3 times the weighted residual norm is
judged zero at the solution, a larger one is calibrated.

A linear measurement model makes the threshold exact: the residual at the
solution is the part ``e`` of the data orthogonal to every column, and the
third column is orthogonal to the others and to ``e``, so its distance from
the span of the earlier columns is its norm. Placed at 1.5 and 10 times the
residual norm (between 0.3, 3 and 30), it tells kappa = 3 from 0, 0.3 or 30.
"""
import numpy as np
import pytest

from calibration import identifiability as ident
from calibration.model import MeasurementModel
from calibration.solver import SolverOptions, solve
from tests.calibration.helpers import dataset

ROWS = 40
RESIDUAL_NORM = 1e-3


class Linear(MeasurementModel):
    """``predicted = A x`` on one channel; ``r = y - A x``, ``W = A``."""

    method = "linear"

    def __init__(self, A, y):
        self.A, self.y = A, y
        self.names = tuple(f"x{j}" for j in range(A.shape[1]))
        self.x0 = self.nominal = np.zeros(A.shape[1])
        self.channels = ("distance",)
        self.row_channel = np.zeros(len(y), dtype=int)
        self.n_poses = len(y)

    def evaluate(self, x):
        return self.y - self.A @ x, self.A.copy()


def _problem(ratio, seed=0):
    """Columns 0, 1 strong; column 2 orthogonal to them and to the residual
    ``e``, with norm ``ratio * ||e||``; data ``y = A x_true + e``, x_true[2] = 0."""
    rng = np.random.default_rng(seed)
    Q, _ = np.linalg.qr(rng.normal(size=(ROWS, 4)))
    strong = rng.normal(size=(ROWS, 2))
    strong -= Q[:, 2:] @ (Q[:, 2:].T @ strong)  # keep columns 0, 1 off q2, q3
    A = np.column_stack([strong, ratio * RESIDUAL_NORM * Q[:, 2]])
    e = RESIDUAL_NORM * Q[:, 3]
    y = A @ np.array([0.3, -0.2, 0.0]) + e
    return A, e, y


@pytest.mark.parametrize("ratio,identifiable", [(1.5, False), (10.0, True)])
def test_solver_default_kappa_is_three(ratio, identifiable):
    A, e, y = _problem(ratio)
    res = solve(Linear(A, y))
    assert res.converged, res.message
    st = res.status[2]
    assert st.identifiable is identifiable, (ratio, st)
    assert np.isclose(np.linalg.norm(res.residual), RESIDUAL_NORM, rtol=1e-6)
    if identifiable:
        assert np.isfinite(res.std[2])
    else:  # no influence: left at its start value, no std, the others unbiased
        assert st.label == ident.NO_INFLUENCE and np.isnan(res.std[2]) and res.x[2] == 0.0
    np.testing.assert_allclose(res.x[:2], [0.3, -0.2], atol=1e-9)


@pytest.mark.parametrize("ratio,identifiable", [(1.5, False), (2.8, False), (3.3, True),
                                                (10.0, True)])
def test_classify_default_kappa_is_three(ratio, identifiable):
    A, e, _ = _problem(ratio)
    ok, dep, rdiag, norms = ident.classify(A, residual=e)
    assert ok.tolist() == [True, True, identifiable] and not dep.any()
    statuses = ident.analyze(A, ["a", "b", "c"], residual=e)
    assert statuses[2].identifiable is identifiable


@pytest.mark.parametrize("kappa,identifiable", [(0.0, True), (1.0, True), (2.0, False)])
def test_kappa_option_reaches_the_check(kappa, identifiable):
    """The option is what decides: at ratio 1.5, kappa 1 keeps the column and 2 drops it."""
    A, _, y = _problem(1.5)
    res = solve(Linear(A, y), SolverOptions(kappa=kappa))
    assert res.status[2].identifiable is identifiable


def test_threshold_is_relative_to_the_weighted_residual():
    """Scaling the data (other units) changes nothing: weights follow sigma."""
    A, _, y = _problem(10.0)
    a = solve(Linear(A, y))
    b = solve(Linear(A * 1e3, y * 1e3))
    assert [s.identifiable for s in a.status] == [s.identifiable for s in b.status]
    np.testing.assert_allclose(a.x, b.x, rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize("method", ["sm-self-redundancy", "sm-plane"])
def test_noisy_constraint_dependencies_stay_dependent(method):
    """With realistic noise, the dependencies that hold only where the model fits
    the data (scale of self-calibration, the plane's translation) are still
    found: the residual-sized column parts are not taken for information."""
    model, _ = dataset(method, seed=11, noise={"distance": 1e-5, "pose": 1e-5})
    res = solve(model)
    assert res.converged, res.message
    assert not res.status[model.names.index("L4")].identifiable


# -- the numerical part of "zero" and the sequential dependency test ----------------
def _unit_qr_diag(cols):
    M = cols / np.linalg.norm(cols, axis=0)
    return np.abs(np.diag(np.linalg.qr(M)[1]))


def test_rank_tol_is_relative_to_the_largest_column():
    rng = np.random.default_rng(3)
    A = rng.normal(size=(30, 3))
    for scale, identifiable in ((1e-10, False), (1e-6, True)):
        B = A.copy()
        B[:, 1] *= scale / np.linalg.norm(B[:, 1]) * np.linalg.norm(B[:, 0])
        ok, dep, _, norms = ident.classify(B * 7.0)  # any overall scale
        assert ok.tolist() == [True, identifiable, True] and not dep.any(), scale
        np.testing.assert_allclose(norms, np.linalg.norm(B * 7.0, axis=0))


def test_candidates_are_respected():
    A = np.random.default_rng(4).normal(size=(20, 4))
    ok, dep, rdiag, _ = ident.classify(A, candidates=np.array([True, False, True, True]))
    assert ok.tolist() == [True, False, True, True] and not dep.any()
    np.testing.assert_allclose(rdiag[[0, 2, 3]], _unit_qr_diag(A[:, [0, 2, 3]]), rtol=1e-12)
    assert rdiag[1] == 0.0


def test_two_dependencies_in_sequence():
    """c2 = c0 + c1 and c4 = c3 - c1: each dependent column is left out and the
    later ones are judged against the kept ones only."""
    rng = np.random.default_rng(5)
    c0, c1, c3, c5 = rng.normal(size=(4, 25))
    A = np.column_stack([c0, c1, c0 + c1, c3, c3 - c1, c5])
    ok, dep, rdiag, _, R = ident.classify(A, return_r=True)
    assert ok.tolist() == [True, True, False, True, False, True]
    assert dep.tolist() == [False, False, True, False, True, False]
    assert R is None  # no single QR covers columns with a dependent one between them
    np.testing.assert_allclose(rdiag[ok], _unit_qr_diag(A[:, ok]), rtol=1e-10)
    assert rdiag[2] < 1e-8 and rdiag[4] < 1e-8
    labels = [s.label for s in ident.analyze(A, list("abcdef"))]
    assert labels[2] == labels[4] == ident.INFLUENCES and labels[5] == ident.IDENTIFIABLE


def test_triangle_of_the_identifiable_columns():
    A = np.random.default_rng(6).normal(size=(15, 4)) * [1.0, 10.0, 0.1, 3.0]
    ok, dep, rdiag, norms, R = ident.classify(A, weights=np.full(15, 4.0), return_r=True)
    assert ok.all() and R is not None and R.shape == (4, 4)
    U = A * 2.0 / (norms)  # weighted (sqrt 4 = 2) unit columns
    np.testing.assert_allclose(R.T @ R, U.T @ U, atol=1e-12)
    assert np.allclose(np.tril(R, -1), 0) and np.allclose(np.abs(np.diag(R)), rdiag)
    np.testing.assert_allclose(norms, 2.0 * np.linalg.norm(A, axis=0))


def test_minimum_poses_is_eq_60():
    assert ident.minimum_poses(13, 2) == 33 and ident.minimum_poses(9, 1) == 45
    assert ident.minimum_poses(7, 0) == 35  # p = 0 counts as one row per pose
