"""The memory design of large fits (issue 43, :mod:`calibration.rowblocks`): a tall
observation matrix is taken a block of rows at a time, never copied whole, and gives
the answers it gives taken whole.

Every test here is deterministic: the answers of the blocked paths against the whole
matrix's (the same classification, distances and statistics to round-off), and the
memory the blocked paths take, measured by :mod:`tracemalloc` (which sees numpy's
allocations), against the matrix's own size; no timing.
"""
import tracemalloc

import numpy as np
import pytest

from calibration import identifiability as ident
from calibration import pose_quality as pq
from calibration import quality as q
from calibration import rowblocks
from calibration.errors import CalibrationError
from calibration.model import MeasurementModel
from calibration.solver import SolverOptions, solve
from calibration.solver import step
from calibration.solver.factored import Scaled
from tests.calibration.helpers import dataset

#: blocks of this many bytes make the small matrices below many blocks
SMALL = 1 << 12


def _matrices(seed=0):
    """A random tall matrix with columns of very different norms, and the same made
    rank-deficient (a combination, a zero column, a column a hair off another)."""
    rng = np.random.default_rng(seed)
    A = rng.normal(size=(1500, 10)) * np.logspace(0, 3, 10)
    B = A.copy()
    B[:, 3] = 2 * B[:, 1] - 0.5 * B[:, 2]
    B[:, 5] = 0.0
    B[:, 7] = B[:, 0] + 1e-12 * rng.normal(size=len(B))
    return {"random": A, "rank-deficient": B}


def _whole_and_blocked(monkeypatch, f):
    """``f()`` with the matrix taken whole, then by blocks of :data:`SMALL` bytes."""
    monkeypatch.setattr(rowblocks, "BLOCK_BYTES", 1 << 40)
    whole = f()
    monkeypatch.setattr(rowblocks, "BLOCK_BYTES", SMALL)
    return whole, f()


def test_spans_cover_the_rows_once_and_are_one_block_where_the_matrix_fits(monkeypatch):
    assert rowblocks.spans(1000, 10) == [(0, 1000)]
    assert rowblocks.spans(0, 10) == [(0, 0)]
    monkeypatch.setattr(rowblocks, "BLOCK_BYTES", 800)
    got = rowblocks.spans(1005, 10)
    assert got[0] == (0, 10) and got[-1] == (1000, 1005)
    assert all(a[1] == b[0] for a, b in zip(got, got[1:]))


def test_the_triangle_of_stacked_blocks_is_the_triangle_of_the_whole():
    rng = np.random.default_rng(1)
    A = rng.normal(size=(700, 6)) @ np.diag([1, 1e3, 1e-3, 5, 1, 1])
    blocks = [(lo, min(lo + 64, 700)) for lo in range(0, 700, 64)]
    R = rowblocks.triangle(lambda lo, hi: np.asfortranarray(A[lo:hi]), blocks, 6)
    R0 = np.linalg.qr(A, mode="r")
    np.testing.assert_allclose(np.abs(R), np.abs(R0), rtol=1e-12, atol=1e-12 * np.abs(R0).max())
    W = rng.normal(size=(50, 4))
    cols = np.array([3, 0, 2])
    w = rng.uniform(0.5, 2.0, size=50)
    np.testing.assert_allclose(rowblocks.column_norms(W, cols, np.sqrt(w)),
                               np.linalg.norm(W[:, cols] * np.sqrt(w)[:, None], axis=0))
    np.testing.assert_allclose(rowblocks.gram(W, cols, w), W[:, cols].T @ (W[:, cols] * w[:, None]))
    d = rng.normal(size=3)
    np.testing.assert_allclose(rowblocks.matvec(W, d, cols), W[:, cols] @ d)


@pytest.mark.parametrize("kind", ["random", "rank-deficient"])
def test_classify_by_blocks_gives_the_whole_matrixs_answer(monkeypatch, kind):
    W = _matrices()[kind]
    rng = np.random.default_rng(2)
    rows, n = W.shape
    w = rng.uniform(0.5, 2.0, size=rows)
    res = 1e-3 * rng.normal(size=rows)
    cand = np.ones(n, bool)
    cand[2] = False
    order = rng.permutation(n)
    for kw in ({}, {"weights": w}, {"weights": w, "residual": res}, {"candidates": cand},
               {"order": order, "weights": w, "candidates": cand, "residual": res},
               {"return_r": True, "weights": w}, {"row_scale": np.sqrt(w), "order": order},
               {"row_scale": 3.0}):
        whole, blocked = _whole_and_blocked(monkeypatch, lambda: ident.classify(W, **kw))
        for a, b in zip(whole[:2], blocked[:2]):
            np.testing.assert_array_equal(a, b, err_msg=str(sorted(kw)))
        for a, b in zip(whole[2:4], blocked[2:4]):
            np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-12 * max(np.abs(a).max(), 1))
        if kw.get("return_r"):
            assert (whole[4] is None) == (blocked[4] is None)
            if whole[4] is not None:
                np.testing.assert_allclose(np.abs(whole[4]), np.abs(blocked[4]), atol=1e-12)
    # the rows' scale is the weights' square root
    a = ident.classify(W, weights=w, order=order)
    b = ident.classify(W, row_scale=np.sqrt(w), order=order)
    for x, y in zip(a, b):
        np.testing.assert_array_equal(x, y)


def test_absorbed_and_the_hat_matrix_by_blocks_give_the_whole_matrixs(monkeypatch):
    W = _matrices()["random"]
    rng = np.random.default_rng(3)
    rows, n = W.shape
    w = rng.uniform(0.5, 2.0, size=rows)
    ident_mask = np.zeros(n, bool)
    ident_mask[[0, 1, 4, 6]] = True
    W = W.copy()
    W[:, 2] = W[:, 0] - 3 * W[:, 4] + 1e-6 * W[:, 9]   # held, absorbed by 0 and 4
    whole, blocked = _whole_and_blocked(
        monkeypatch, lambda: ident.absorbed(W, w, ident_mask, ~ident_mask))
    assert whole == blocked and 2 in whole[0] and 2 in whole[4]
    active = ~np.isin(np.arange(n), [3, 5, 7])
    (Uw, hw, pw), (Ub, hb, pb) = _whole_and_blocked(monkeypatch, lambda: (
        q.hat_basis(W, w, active), q.leverage(W, w, active),
        q.prediction_leverage(W, w, active, W[:7], w[:7])))
    np.testing.assert_allclose(Ub @ Ub.T, Uw @ Uw.T, atol=1e-12)
    np.testing.assert_allclose(hb, hw, rtol=1e-11, atol=1e-14)
    np.testing.assert_allclose(pb, pw, rtol=1e-11)
    # the basis written over the matrix's own rows
    C = W.copy()
    Uo = q.hat_basis(C, w, active, overwrite=True)
    assert np.shares_memory(Uo, C)
    np.testing.assert_allclose(Uo @ Uo.T, Uw @ Uw.T, atol=1e-12)


def test_pose_blocks_are_those_of_each_poses_rows():
    """Each pose's rows found by one sort: the blocks of a pose by pose search."""
    rng = np.random.default_rng(4)
    A = rng.normal(size=(300, 5))
    U = np.linalg.qr(A)[0]
    w = rng.uniform(0.5, 2.0, size=300)
    r = rng.normal(size=300)
    row_pose = rng.permutation(np.repeat(np.arange(100), 3))
    got = pq.pose_blocks(r, U, w, row_pose)
    assert [b.pose for b in got] == list(range(100))
    for b in got:
        np.testing.assert_array_equal(b.rows, np.flatnonzero(row_pose == b.pose))
        H = U[b.rows] @ U[b.rows].T
        rw = r[b.rows] * np.sqrt(w[b.rows])
        np.testing.assert_array_equal(b.deleted, np.linalg.solve(np.eye(3) - H, rw)
                                      / np.sqrt(w[b.rows]))


def _peak(f, *args, **kwargs) -> int:
    """The most memory ``f`` held at once beyond what there was before it (bytes)."""
    tracemalloc.start()
    try:
        tracemalloc.reset_peak()
        base = tracemalloc.get_traced_memory()[0]
        f(*args, **kwargs)
        return tracemalloc.get_traced_memory()[1] - base
    finally:
        tracemalloc.stop()


def test_a_tall_matrix_is_never_copied_whole(monkeypatch):
    """classify (weighted, judged in another order: the final status of a fit), the
    solver's factorization, absorbed and the hat matrix's diagonal take a few blocks of
    a 200 000 x 40 matrix at a time, not copies of it (they took four to six): the most
    each holds at once beyond the matrix is below half of it."""
    monkeypatch.setattr(rowblocks, "BLOCK_BYTES", 4 << 20)
    rng = np.random.default_rng(5)
    W = rng.normal(size=(200_000, 40))
    w = rng.uniform(0.5, 2.0, size=len(W))
    r = 1e-3 * rng.normal(size=len(W))
    order = rng.permutation(40)
    size = W.nbytes
    active = np.ones(40, bool)
    active[::3] = False
    limit = 0.5 * size
    assert _peak(ident.classify, W, weights=w, residual=r, order=order) < limit
    assert _peak(Scaled, None, {}, W, np.ones(40), np.sqrt(w), r) < limit
    assert _peak(Scaled, None, {}, W, np.ones(26), 0.5, r,
                 cols=np.flatnonzero(active)) < limit
    assert _peak(ident.absorbed, W, w, active, ~active) < limit
    assert _peak(q.leverage, W, w, active) < limit
    # the basis itself is as large as its columns, and no more
    U = np.empty((len(W), int(active.sum())))
    assert _peak(q.hat_basis, W, w, active) < U.nbytes + limit
    C = W.copy()
    assert _peak(q.hat_basis, C, w, active, overwrite=True) < limit


#: noisy readings (the fits' sigma and std are then the noise's, not round-off's)
NOISE = {"distance": 1e-5, "tilt": 1e-4, "pose": 1e-5, "position": 1e-5}


@pytest.mark.parametrize("method", ["sm-distance-tilt", "sm-full-pose", "pm-tilt"])
def test_a_fit_by_blocks_letting_its_matrix_go_is_the_same_fit(monkeypatch, method):
    """The whole solver with every matrix taken by small blocks (a few rows each; several
    channels: their leverages too), and let go before each evaluation at another point:
    the same iterations, evaluations and classification and, to round-off, estimates,
    std and condition number."""
    model, _ = dataset(method, seed=4, noise=NOISE)
    whole = solve(model, SolverOptions())
    monkeypatch.setattr(rowblocks, "BLOCK_BYTES", 2048)
    monkeypatch.setattr(step, "RELEASE_BYTES", 0)
    blocked = solve(model, SolverOptions())
    assert whole.converged and blocked.converged
    assert (whole.iterations, whole.nfev) == (blocked.iterations, blocked.nfev)
    assert [s.label for s in whole.status] == [s.label for s in blocked.status]
    ok = np.isfinite(whole.std)
    np.testing.assert_allclose(blocked.x, whole.x, rtol=1e-10, atol=1e-14)
    np.testing.assert_allclose(blocked.std[ok], whole.std[ok], rtol=1e-7)
    assert blocked.condition_number == pytest.approx(whole.condition_number, rel=1e-9)


class Exponential(MeasurementModel):
    """``predicted = a exp(b t) + c t`` on many rows; ``b >= 2.9`` cannot be evaluated
    (a CalibrationError, as a PM that cannot assemble). Counts its evaluations."""

    method = "exponential"
    names = ("a", "b", "c")
    channels = ("distance",)

    def __init__(self, x0):
        rng = np.random.default_rng(0)
        self.t = np.linspace(0.0, 2.0, 3000)
        self.y = 2 * np.exp(1.3 * self.t) + 0.5 * self.t + 1e-3 * rng.normal(size=3000)
        self.x0 = self.nominal = np.asarray(x0, float)
        self.row_channel = np.zeros(3000, dtype=int)
        self.n_poses = 3000
        self.calls = 0

    def evaluate(self, x):
        self.calls += 1
        a, b, c = x
        if b >= 2.9:
            raise CalibrationError("outside the model's domain")
        e = np.exp(b * self.t)
        return self.y - a * e - c * self.t, np.column_stack([e, a * self.t * e, self.t])


@pytest.mark.parametrize("x0", [(50.0, 0.0, 0.0), (0.1, 2.5, 0.0)])
def test_a_rejected_step_evaluates_the_let_go_matrix_again(monkeypatch, x0):
    """Steps rejected (the cost rose, or the model could not be evaluated there): the
    matrix let go before the trial is evaluated again at the current point, not
    counted as an evaluation of the fit, and the fit is the same."""
    keep = Exponential(x0)
    kept = solve(keep, SolverOptions())
    monkeypatch.setattr(step, "RELEASE_BYTES", 0)
    go = Exponential(x0)
    let_go = solve(go, SolverOptions())
    assert kept.converged and let_go.converged
    assert (kept.iterations, kept.nfev) == (let_go.iterations, let_go.nfev)
    assert keep.calls == kept.nfev < go.calls  # (rejected steps: evaluated again)
    np.testing.assert_allclose(let_go.x, kept.x, rtol=1e-12)
    np.testing.assert_allclose(let_go.std, kept.std, rtol=1e-10)
