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


@pytest.mark.parametrize("ratio,identifiable", [(1.5, False), (10.0, True)])
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
