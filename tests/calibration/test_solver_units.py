"""Algorithm 2 (calibration.solver) on problems whose answer is known in closed
form: small linear models (the solution, sigma, covariance and cost are those
of ordinary or weighted least squares), a tiny nonlinear one (against scipy),
and the pieces on their own (the damped step, Bartlett's test). Each test
takes milliseconds, so that the solver's mutation run (bench/mutation.py
solver) can use them alone (docs/testing.md).
"""
import math
from dataclasses import replace

import numpy as np
import pytest
from scipy import stats
from scipy.optimize import brentq, least_squares

from calibration import identifiability as ident
from calibration.errors import CalibrationError
from calibration.model import MeasurementModel
from calibration.solver import SolverOptions, solve
from calibration.solver import factored, step, stopping
from calibration.solver.factored import Scaled, masks
from calibration.solver.weighting import HOMOGENEITY_ALPHA, _homogeneous


class Linear(MeasurementModel):
    """``predicted = A x``: ``r = y - A (x)``, ``W = A``; rows of ``channel``
    (index per row) into ``channels``."""

    method = "linear"

    def __init__(self, A, y, channel=None, channels=("distance",), x0=None, groups=()):
        self.A, self.y = np.asarray(A, float), np.asarray(y, float)
        n = self.A.shape[1]
        self.names = tuple(f"x{j}" for j in range(n))
        self.x0 = self.nominal = np.zeros(n) if x0 is None else np.asarray(x0, float)
        self.channels = channels
        self.row_channel = (np.zeros(len(y), dtype=int) if channel is None
                            else np.asarray(channel, dtype=int))
        self.n_poses = len(y)
        self.noise_groups = groups

    def evaluate(self, x):
        return self.y - self.A @ x, self.A.copy()


class Exponential(MeasurementModel):
    """``predicted = a exp(b t)``; outside ``b < 3`` the model cannot be
    evaluated (a CalibrationError, as a PM that cannot assemble)."""

    method = "exponential"
    names = ("a", "b")
    channels = ("distance",)

    def __init__(self, t, y, x0, limit=3.0):
        self.t, self.y, self.limit = t, y, limit
        self.x0 = self.nominal = np.asarray(x0, float)
        self.row_channel = np.zeros(len(t), dtype=int)
        self.n_poses = len(t)

    def evaluate(self, x):
        a, b = x
        if b >= self.limit:
            raise CalibrationError("outside the model's domain")
        e = np.exp(b * self.t)
        return self.y - a * e, np.column_stack([e, a * self.t * e])


def _linear(rows=30, n=3, noise=1e-3, seed=0, scales=(1.0, 20.0, 0.05)):
    rng = np.random.default_rng(seed)
    A = rng.normal(size=(rows, n)) * np.asarray(scales[:n])
    truth = rng.normal(size=n)
    y = A @ truth + noise * rng.normal(size=rows)
    return A, y, truth


def _ols(A, y):
    x = np.linalg.lstsq(A, y, rcond=None)[0]
    r = y - A @ x
    s2 = float(r @ r) / (len(y) - A.shape[1])
    return x, r, s2, s2 * np.linalg.inv(A.T @ A)


def _t2(nu):
    """Variance of Student's t with ``nu`` degrees of freedom: what an estimated
    sigma's own uncertainty multiplies the covariance by (eq. 52 with eq. 51's sigma)."""
    return nu / (nu - 2)


# -- one channel, estimated sigma: ordinary least squares ---------------------------------
def test_linear_solution_sigma_covariance_and_cost_are_least_squares():
    A, y, _ = _linear()
    x, r, s2, cov = _ols(A, y)
    res = solve(Linear(A, y))
    assert res.converged and res.message.startswith("converged in ")
    assert f"in {res.iterations} iterations" in res.message and "< 1e-10" in res.message
    np.testing.assert_allclose(res.x, x, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(res.residual, r, rtol=1e-6, atol=1e-12)
    assert res.sigma == pytest.approx({"distance": math.sqrt(s2)}, rel=1e-9)  # eq. 51
    assert not res.sigma_known
    cov = cov * _t2(30 - 3)  # eq. 52, and sigma's own uncertainty (27 degrees of freedom)
    np.testing.assert_allclose(res.covariance, cov, rtol=1e-8)
    np.testing.assert_allclose(res.std, np.sqrt(np.diag(cov)), rtol=1e-8)
    assert res.sigma_dof == pytest.approx({"distance": 27.0}, rel=1e-9)
    assert res.residual_rms["distance"] == pytest.approx(math.sqrt(r @ r / len(y)), rel=1e-9)
    # cost 0.5 r^T L r with L = 1/sigma^2: half the degrees of freedom
    assert res.cost == pytest.approx(0.5 * (len(y) - 3), rel=1e-9)
    H = 1 / np.linalg.norm(A, axis=0)
    assert res.condition_number == pytest.approx(np.linalg.cond(A * H), rel=1e-9)
    assert res.n_rows == 30 and res.n_identifiable == 3 and res.covariance_names == res.names
    assert res.nfev == res.iterations and res.wall_time > 0  # start + accepted steps
    assert [s.label for s in res.status] == [ident.IDENTIFIABLE] * 3
    assert res.value("x1") == res.x[1] and res.error_of("x2") == res.std[2]
    np.testing.assert_array_equal(res.x0, np.zeros(3))


def test_linear_history_records_each_iteration():
    A, y, _ = _linear()
    x, _, s2, cov = _ols(A, y)
    seen = []
    res = solve(Linear(A, y), callback=lambda k, it: seen.append((k, it)))
    assert [k for k, _ in seen] == list(range(1, res.iterations + 1))
    assert [it for _, it in seen] == list(res.history)
    last = res.history[-1]
    assert last.step < 1e-10 and all(h.step >= 1e-10 for h in res.history[:-1])
    np.testing.assert_allclose(last.x, x, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(last.variance, np.diag(cov), rtol=1e-6)
    assert last.sigma == pytest.approx({"distance": math.sqrt(s2)}, rel=1e-6)
    assert last.condition_number == pytest.approx(res.condition_number, rel=1e-9)
    # the first step starts from x0 = 0: cost 0.5 y^T y (L = I in the first iteration)
    assert res.history[0].cost == pytest.approx(0.5 * float(y @ y), rel=1e-12)
    assert res.history[0].step == pytest.approx(np.abs(x).max(), rel=1e-3)


def test_history_condition_number_is_that_of_each_iteration_and_survives_pickling():
    """Each iteration's condition number is read from its own triangle when
    asked for: that of the scaled, weighted matrix at its x (the first at x0 = 0
    with L = I), kept through a pickle round trip; the record is read-only."""
    import pickle

    A, y, _ = _linear()
    res = solve(Linear(A, y))
    H = 1 / np.linalg.norm(A, axis=0)
    for it in res.history:  # linear: the scaled matrix is the same at every x
        assert it.condition_number == pytest.approx(np.linalg.cond(A * H), rel=1e-9)
    back = pickle.loads(pickle.dumps(res))
    assert [h.condition_number for h in back.history] == [h.condition_number
                                                          for h in res.history]
    np.testing.assert_array_equal(back.history[-1].variance, res.history[-1].variance)
    with pytest.raises(AttributeError):
        res.history[0].step = 1.0
    assert res.iterations <= 4


def test_known_sigma_weights_and_scales_the_covariance():
    A, y, _ = _linear()
    x, r, _, _ = _ols(A, y)
    s = 2e-3
    res = solve(Linear(A, y), SolverOptions(sigma={"distance": s}))
    assert res.sigma_known and res.sigma == {"distance": s}
    np.testing.assert_allclose(res.x, x, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(res.covariance, s * s * np.linalg.inv(A.T @ A), rtol=1e-8)
    assert res.cost == pytest.approx(0.5 * float(r @ r) / s ** 2, rel=1e-6)
    np.testing.assert_allclose(res.history[-1].variance, s * s * np.diag(np.linalg.inv(A.T @ A)),
                               rtol=1e-6)


@pytest.mark.parametrize("opts", [dict(scale_columns=False), dict(weight_errors=False),
                                  dict(adaptive=False), dict(recheck=False), dict(damping=0.0),
                                  dict(damping=0.3)])
def test_options_do_not_change_a_linear_answer(opts):
    A, y, _ = _linear()
    x, _, s2, cov = _ols(A, y)
    res = solve(Linear(A, y), SolverOptions(**opts))
    assert res.converged, res.message
    np.testing.assert_allclose(res.x, x, rtol=1e-8, atol=1e-12)
    if opts != dict(weight_errors=False):   # L = I: eq. 52 as the report writes it
        cov = cov * _t2(27)
    np.testing.assert_allclose(res.covariance, cov, rtol=1e-6)
    if opts == dict(scale_columns=False):
        assert res.condition_number == pytest.approx(np.linalg.cond(A), rel=1e-9)
    if opts == dict(damping=0.3):  # a damped step needs more iterations
        assert res.iterations > solve(Linear(A, y)).iterations


def test_damping_defaults_to_the_method_s():
    A, y, _ = _linear()
    m = Linear(A, y)
    m.default_damping = 0.5
    slow = solve(m)
    assert slow.iterations == solve(Linear(A, y), SolverOptions(damping=0.5)).iterations
    assert slow.iterations > solve(Linear(A, y)).iterations


def test_epsilon_and_iteration_limit():
    A, y, _ = _linear()
    res = solve(Linear(A, y), SolverOptions(max_iter=1))
    assert not res.converged and res.iterations == 1
    assert res.message == "no convergence within 1 iterations"
    x = _ols(A, y)[0]
    start = x + [1e-4, -2e-4, 5e-5]
    loose = solve(Linear(A, y, x0=start), SolverOptions(epsilon=3e-4))
    assert loose.converged and loose.iterations == 1 and "< 0.0003" in loose.message
    np.testing.assert_array_equal(loose.x, start)  # the step was below epsilon: not taken
    assert loose.history[0].step == pytest.approx(2e-4, rel=1e-3)
    tight = solve(Linear(A, y, x0=start), SolverOptions(epsilon=1.9e-4))
    assert tight.iterations == 2 and np.allclose(tight.x, x, rtol=1e-6)


def test_nothing_identifiable_at_the_solution_is_refused():
    """Stopped far from the solution (epsilon 10), the residual dwarfs every
    column: nothing is identifiable there, which is a refusal, not a crash."""
    A, y, _ = _linear()
    with pytest.raises(CalibrationError, match=r"^no parameter can be identified at the solution: "
                                               r"every column is within kappa = 3 times the "
                                               r"residual there \(the model does not fit the "
                                               r"data: a local minimum, or a fixed parameter far "
                                               r"from its value\)$"):
        solve(Linear(A, y), SolverOptions(epsilon=10.0))


# -- identifiable-set selection ----------------------------------------------------------
def test_dependent_and_zero_columns_and_fixed_parameters():
    rng = np.random.default_rng(1)
    c0, c1, c3 = rng.normal(size=(3, 25))
    A = np.column_stack([c0, c1, 2 * c0 - c1, np.zeros(25), c3])
    truth = np.array([0.4, -0.7, 0.0, 0.0, 0.0])
    y = A @ truth + 1e-3 * rng.normal(size=25)
    x0 = np.array([0.0, 0.0, 0.25, -0.5, 0.0])
    res = solve(Linear(A, y, x0=x0))
    assert res.converged, res.message
    assert [s.label for s in res.status] == [ident.IDENTIFIABLE, ident.IDENTIFIABLE,
                                             ident.INFLUENCES, ident.NO_INFLUENCE,
                                             ident.IDENTIFIABLE]
    keep = [0, 1, 4]
    x, _, s2, cov = _ols(A[:, keep], y - A[:, 2] * 0.25)
    np.testing.assert_allclose(res.x[keep], x, rtol=1e-9)
    assert res.x[2] == 0.25 and res.x[3] == -0.5  # left at their start values
    assert np.isnan(res.std[[2, 3]]).all() and res.covariance.shape == (3, 3)
    np.testing.assert_allclose(res.covariance, cov * _t2(25 - 3), rtol=1e-8)
    assert res.covariance_names == ("x0", "x1", "x4") and res.n_identifiable == 3
    assert np.isnan(res.history[-1].variance[[2, 3]]).all()
    np.testing.assert_allclose(res.history[-1].variance[keep], np.diag(cov), rtol=1e-6)
    # fixed: kept at the start value, not calibrated, the others fitted without it
    fx = solve(Linear(A, y, x0=x0), SolverOptions(fixed=("x4",)))
    assert fx.converged, fx.message
    assert fx.x[4] == 0.0 and not fx.status[4].identifiable and fx.n_identifiable == 2
    np.testing.assert_allclose(fx.x[:2], _ols(A[:, :2], y - A[:, 2] * 0.25)[0], rtol=1e-9)


def test_parameter_dropped_at_the_solution_returns_to_its_start():
    """A column at 1.5 times the residual norm is calibrated from the structural
    check, then judged zero at the solution (kappa = 3): it goes back to x0
    and the others are refitted without it."""
    rng = np.random.default_rng(2)
    Q, _ = np.linalg.qr(rng.normal(size=(40, 4)))
    strong = rng.normal(size=(40, 2))
    strong -= Q[:, 2:] @ (Q[:, 2:].T @ strong)
    A = np.column_stack([strong, 1.5e-3 * Q[:, 2]])
    y = A @ np.array([0.3, -0.2, 0.0]) + 1e-3 * Q[:, 3] + 2e-3 * Q[:, 2]
    res = solve(Linear(A, y, x0=[0.0, 0.0, 0.1]))
    assert res.status[2].label == ident.NO_INFLUENCE and res.x[2] == 0.1
    np.testing.assert_allclose(res.x[:2], [0.3, -0.2], atol=1e-9)
    assert solve(Linear(A, y, x0=[0.0, 0.0, 0.1]), SolverOptions(recheck=False)).status[2].identifiable


def test_refusals_name_the_problem():
    A, y, _ = _linear(rows=3)
    with pytest.raises(CalibrationError, match=r"3 poses give 3 equations for up to 3 "
                                               r"parameters; at least 4 poses .*recommended 15"):
        solve(Linear(A, y))
    A, y, _ = _linear(rows=4)
    assert solve(Linear(A, y)).converged  # one degree of freedom is enough
    with pytest.raises(CalibrationError,
                       match="^no parameter can be identified from these measurements$"):
        solve(Linear(np.zeros((5, 2)), np.ones(5)))
    with pytest.raises(CalibrationError, match=r"unknown channel\(s\) \['tilt'\]"):
        solve(Linear(A, y), SolverOptions(sigma={"tilt": 1.0}))
    for bad in (0.0, -1.0, float("nan"), float("inf")):
        with pytest.raises(CalibrationError, match="must be a positive number"):
            solve(Linear(A, y), SolverOptions(sigma={"distance": bad}))
    yb = y.copy()
    yb[1] = np.nan
    with pytest.raises(CalibrationError, match="^the model gives non-finite values at the start"):
        solve(Linear(A, yb))


# -- two channels: per-channel weights (eq. 51 per channel) --------------------------------
def _two_channels(s0=1e-3, s1=3e-2, rows=(40, 30), seed=3, groups=()):
    rng = np.random.default_rng(seed)
    A = rng.normal(size=(sum(rows), 3)) * [1.0, 5.0, 0.2]
    ch = np.repeat([0, 1], rows)
    y = A @ np.array([0.5, -0.1, 2.0]) + np.where(ch == 0, s0, s1) * rng.normal(size=len(ch))
    return Linear(A, y, channel=ch, channels=("distance", "tilt"), groups=groups), A, y, ch


def _channel_sigmas(A, r, ch, w):
    """Each channel's sigma: its residual over its rows less its leverages in the
    fit weighted by ``w``."""
    Aw = A * np.sqrt(w)[:, None]
    lev = np.einsum("ij,ij->i", Aw @ np.linalg.inv(Aw.T @ Aw), Aw)
    return [math.sqrt(float(r[ch == c] @ r[ch == c]) / ((ch == c).sum() - lev[ch == c].sum()))
            for c in range(ch.max() + 1)]


def _wls(A, y, w):
    Aw = A * np.sqrt(w)[:, None]
    x = np.linalg.lstsq(Aw, y * np.sqrt(w), rcond=None)[0]
    return x, np.linalg.inv(A.T @ (A * w[:, None]))


def test_per_channel_weights_are_the_channels_sigmas():
    model, A, y, ch = _two_channels()
    res = solve(model)
    assert res.converged, res.message
    used = res.history[-1].sigma  # the weights of the last round
    w_used = 1 / np.array([used["distance"], used["tilt"]])[ch] ** 2
    x, _ = _wls(A, y, w_used)
    np.testing.assert_allclose(res.x, x, rtol=1e-9)
    # final sigma: each channel's residual over its degrees of freedom, which are its
    # rows less the leverages its rows hold in the weighted fit
    r = y - A @ res.x
    Aw = A * np.sqrt(w_used)[:, None]
    lev = np.einsum("ij,ij->i", Aw @ np.linalg.inv(Aw.T @ Aw), Aw)
    for c, name in enumerate(model.channels):
        m = ch == c
        want = math.sqrt(float(r[m] @ r[m]) / (m.sum() - lev[m].sum()))
        assert res.sigma[name] == pytest.approx(want, rel=1e-9)
        assert res.residual_rms[name] == pytest.approx(math.sqrt(r[m] @ r[m] / m.sum()), rel=1e-9)
        assert abs(res.sigma[name] / used[name] - 1) <= 0.05  # no material change left
        assert res.sigma_dof[name] == pytest.approx(m.sum() - lev[m].sum(), rel=1e-9)
    # the covariance: each channel's sigma with its own uncertainty (its degrees of freedom)
    wc = 1 / np.array([res.sigma[n] ** 2 * _t2(res.sigma_dof[n]) for n in model.channels])[ch]
    np.testing.assert_allclose(res.covariance, np.linalg.inv(A.T @ (A * wc[:, None])), rtol=1e-8)
    w = 1 / np.array([res.sigma["distance"], res.sigma["tilt"]])[ch] ** 2
    assert res.cost == pytest.approx(0.5 * float(r @ (w * r)), rel=1e-9)
    # the sigmas differ thirtyfold; the pooled fit would be a different (worse) answer
    assert 10 < res.sigma["tilt"] / res.sigma["distance"] < 100
    assert not np.allclose(res.x, _ols(A, y)[0], rtol=1e-6)
    s0 = res.history[0].sigma  # pooled: one sigma (eq. 51) for all rows until the solution
    assert s0["distance"] == s0["tilt"] and 1e-3 < s0["tilt"] < 3e-2
    var_last = np.diag(np.linalg.inv(A.T @ (A * w_used[:, None])))
    np.testing.assert_allclose(res.history[-1].variance, var_last, rtol=1e-6)


def test_a_channel_without_degrees_of_freedom_shares_the_others_sigma():
    """Two parameters that only the first channel's two rows see: the fit spends
    both rows on them, their residual is round-off and says nothing of that
    channel's noise (eq. 51 would divide round-off by round-off). Both channels
    then get one sigma, the second channel's residual over the degrees of freedom
    left, as the pooled round has it, for the rest of the fit."""
    rng = np.random.default_rng(5)
    A = np.zeros((32, 4))
    A[:2, :2] = rng.normal(size=(2, 2))
    A[2:, 2:] = rng.normal(size=(30, 2))
    A[2:, :2] = 0.0
    ch = np.repeat([0, 1], [2, 30])
    y = A @ np.array([0.5, -0.1, 2.0, 1.0]) + np.where(ch == 0, 1e-3, 3e-2) * rng.normal(size=32)
    res = solve(Linear(A, y, channel=ch, channels=("distance", "tilt")))
    assert res.converged, res.message
    r = y - A @ res.x
    assert float(r[:2] @ r[:2]) < 1e-28           # the first channel fitted exactly
    want = math.sqrt(float(r @ r) / (32 - 4))
    assert res.sigma == pytest.approx({"distance": want, "tilt": want}, rel=1e-9)
    # the shared sigma is the tilt's noise, not the distance's: the distance keeps its
    # own (none), and the covariance credits it the fewest degrees of freedom
    assert res.sigma_dof["tilt"] == pytest.approx(28.0, rel=1e-9)
    assert abs(res.sigma_dof["distance"]) < 1e-9
    np.testing.assert_allclose(res.x, _ols(A, y)[0], rtol=1e-9)
    cov = np.linalg.inv(A.T @ A) * want ** 2
    t = np.where(np.arange(4) < 2, math.sqrt(_t2(3.0)), math.sqrt(_t2(28.0)))
    np.testing.assert_allclose(np.sqrt(np.diag(res.covariance)), np.sqrt(np.diag(cov)) * t,
                               rtol=1e-6)


def test_known_sigma_per_channel():
    model, A, y, ch = _two_channels()
    sig = {"distance": 1e-3, "tilt": 3e-2}
    res = solve(model, SolverOptions(sigma=sig))
    w = 1 / np.array([1e-3, 3e-2])[ch] ** 2
    x, cov = _wls(A, y, w)
    assert res.sigma == sig and res.sigma_known
    np.testing.assert_allclose(res.x, x, rtol=1e-9)
    np.testing.assert_allclose(res.covariance, cov, rtol=1e-8)
    assert all(h.sigma == sig for h in res.history)
    assert res.rounds == 1  # sigmas that differ: weighted from the first step, one round
    # the other path (the restart's where these weights from the first step miss): a
    # pooled first round, the stated weights from its solution on; the same minimum,
    # and every record at the stated sigma (the pooled round's variance and condition
    # number formed at the stated weights: W is A everywhere here)
    from calibration.solver import rounds

    other = rounds._solve(model, SolverOptions(sigma=sig), None, 0.0, other_path=True)[0]
    assert other.rounds == 2 and other.sigma == sig
    np.testing.assert_allclose(other.x, x, rtol=1e-9)
    np.testing.assert_allclose(other.covariance, cov, rtol=1e-8)
    W = model.evaluate(model.x0)[1]
    cond = np.linalg.cond(W / np.linalg.norm(W, axis=0) / np.array([1e-3, 3e-2])[ch][:, None])
    for h in other.history:
        assert h.sigma == sig
        np.testing.assert_allclose(h.variance, np.diag(cov), rtol=1e-8)
        assert h.condition_number == pytest.approx(cond, rel=1e-10)
    r0 = model.evaluate(model.x0)[0] / np.array([1e-3, 3e-2])[ch]
    assert other.history[0].cost == pytest.approx(0.5 * float(r0 @ r0), rel=1e-12)
    # one channel known, the other estimated
    part = solve(model, SolverOptions(sigma={"distance": 1e-3}))
    assert part.sigma["distance"] == 1e-3 and not part.sigma_known
    assert part.sigma["tilt"] == pytest.approx(3e-2, rel=0.3)
    # its minimum is the weighted one: the stated sigma and the other's estimate, never 1
    used = part.history[-1].sigma
    assert used["distance"] == 1e-3 and abs(used["tilt"] / part.sigma["tilt"] - 1) <= 0.05
    w_used = 1 / np.array([used["distance"], used["tilt"]])[ch] ** 2
    np.testing.assert_allclose(part.x, _wls(A, y, w_used)[0], rtol=1e-9)
    assert set(part.sigma_dof) == {"tilt"}      # the stated sigma is not uncertain


def test_unweighted_two_channels_is_ordinary_least_squares():
    model, A, y, ch = _two_channels()
    res = solve(model, SolverOptions(weight_errors=False))
    x, r, s2, _ = _ols(A, y)
    np.testing.assert_allclose(res.x, x, rtol=1e-9)
    assert all(set(h.sigma.values()) == {h.sigma["distance"]} for h in res.history)
    assert res.history[-1].sigma["distance"] == pytest.approx(math.sqrt(s2), rel=1e-6)


def test_channels_of_one_sensor_share_a_sigma_unless_bartlett_tells_them_apart():
    same, A, y, ch = _two_channels(s0=1e-3, s1=1e-3, groups=(("distance", "tilt"),))
    res = solve(same)
    assert res.sigma["distance"] == res.sigma["tilt"]
    x, r, s2, cov = _ols(A, y)
    np.testing.assert_allclose(res.x, x, rtol=1e-9)
    assert res.sigma["distance"] == pytest.approx(math.sqrt(s2), rel=1e-9)
    np.testing.assert_allclose(res.covariance, cov * _t2(len(y) - 3), rtol=1e-8)
    apart = solve(Linear(A, y, channel=ch, channels=("distance", "tilt")))
    assert apart.sigma["distance"] != apart.sigma["tilt"]
    differ, *_ = _two_channels(groups=(("distance", "tilt"),))
    d = solve(differ)
    assert d.sigma["tilt"] / d.sigma["distance"] > 10


def _bartlett_inputs(scale, sizes, seed=0):
    rng = np.random.default_rng(seed)
    samples = [rng.normal(size=n) * (scale if i == 0 else 1.0) for i, n in enumerate(sizes)]
    rss_dof = [(float(((s - s.mean()) ** 2).sum()), len(s) - 1) for s in samples]
    return samples, rss_dof


def _bartlett_p(scale, sizes):
    return stats.bartlett(*_bartlett_inputs(scale, sizes)[0]).pvalue


@pytest.mark.parametrize("sizes", [(12, 9, 15), (20, 14)])
def test_homogeneity_is_bartlett_s_test_at_its_threshold(sizes):
    """Against scipy's Bartlett test on the same samples, just either side of
    alpha = 0.01 (the scale of one group where scipy's p crosses it)."""
    assert HOMOGENEITY_ALPHA == 0.01
    cross = brentq(lambda s: _bartlett_p(s, sizes) - HOMOGENEITY_ALPHA, 1.0, 6.0, xtol=1e-9)
    for s in (cross * (1 - 1e-5), cross * (1 + 1e-5), 1.0, 6.0):
        pv = _bartlett_p(s, sizes)
        assert _homogeneous(_bartlett_inputs(s, sizes)[1]) is bool(pv > HOMOGENEITY_ALPHA), (s, pv)


def test_homogeneity_needs_two_usable_groups():
    assert not _homogeneous([(1.0, 10)])
    assert not _homogeneous([(1.0, 10), (0.0, 10)])  # no scatter: not a usable group
    assert not _homogeneous([(1.0, 10), (1.0, 0.5)])  # half a degree of freedom: not usable
    assert _homogeneous([(1.0, 10), (1.1, 11), (0.0, 5)])
    assert _homogeneous([(1.0, 10), (0.3, 0.6)]) is bool(
        stats.chi2.sf(_bartlett_t([(1.0, 10), (0.3, 0.6)]), 1) > 0.01)


def _bartlett_t(rd):
    nu = sum(d for _, d in rd)
    sp = sum(rc for rc, _ in rd) / nu
    t = nu * math.log(sp) - sum(d * math.log(rc / d) for rc, d in rd)
    return t / (1 + (sum(1 / d for _, d in rd) - 1 / nu) / (3 * (len(rd) - 1)))


# -- nonlinear: against scipy ----------------------------------------------------------------
def _exp_data(noise=1e-3, seed=4):
    rng = np.random.default_rng(seed)
    t = np.linspace(0.0, 1.0, 25)
    return t, 1.5 * np.exp(-0.8 * t) + noise * rng.normal(size=t.size)


def test_nonlinear_matches_scipy_least_squares():
    t, y = _exp_data()
    res = solve(Exponential(t, y, [1.0, 0.0]))
    ref = least_squares(lambda p: y - p[0] * np.exp(p[1] * t), [1.0, 0.0], xtol=1e-15,
                        ftol=1e-15, gtol=1e-15)
    assert res.converged, res.message
    np.testing.assert_allclose(res.x, ref.x, rtol=1e-9)
    J = ref.jac
    s2 = float(ref.fun @ ref.fun) / (t.size - 2)
    np.testing.assert_allclose(res.covariance, s2 * _t2(t.size - 2) * np.linalg.inv(J.T @ J),
                               rtol=1e-6)
    assert 2 < res.iterations < 30
    steps = [h.step for h in res.history]
    # a model with a domain: every point reported was evaluated (no step predicted)
    assert steps[-1] < 1e-10 and steps[-2] < 1e-4  # quadratic convergence at the end
    np.testing.assert_array_equal(res.residual, Exponential(t, y, res.x).evaluate(res.x)[0])


class Everywhere(Exponential):
    evaluates_everywhere = True


def _gauss_newton_step(model, res) -> float:
    """Largest component of the undamped step at ``res.x`` with its final weights."""
    r, W = model.evaluate(res.x)
    act = np.array([s.identifiable for s in res.status])
    w = 1.0 / np.array([res.sigma[ch] for ch in model.channels])[model.row_channel]
    return float(np.abs(np.linalg.lstsq(W[:, act] * w[:, None], r * w, rcond=None)[0]).max())


@pytest.mark.parametrize("noise,seed", [(1e-3, 0), (1e-3, 1), (1e-3, 5), (0.0, 0), (0.0, 3)])
def test_a_model_evaluated_everywhere_ends_on_a_predicted_step(noise, seed):
    """These fits end on a step the solver predicts and does not evaluate after
    (one evaluation fewer than with a domain): the undamped step from there is
    below epsilon, the residual the model's own, the solution the same."""
    t, y = _exp_data(noise=noise, seed=seed)
    model = Everywhere(t, y, [1.0, 0.0], limit=np.inf)
    res = solve(model)
    assert res.converged and "predicted for the step after the last" in res.message
    assert res.nfev == res.iterations  # the start, and every step but the last
    steps = [h.step for h in res.history]
    assert steps[-1] < 1e-5 and steps[-1] < stopping.SETTLED_CONTRACTION * steps[-2]
    assert _gauss_newton_step(model, res) < 1e-10
    np.testing.assert_allclose(model.evaluate(res.x)[0], res.residual, rtol=0, atol=1e-12)
    ref = solve(Exponential(t, y, [1.0, 0.0]))
    assert ref.nfev == res.nfev + 1 and "predicted" not in ref.message
    np.testing.assert_allclose(res.x, ref.x, rtol=1e-10)


def test_noise_free_nonlinear_recovers_the_truth():
    t = np.linspace(0.0, 1.0, 25)
    res = solve(Exponential(t, 1.5 * np.exp(-0.8 * t), [1.0, 0.0]))
    assert res.converged
    np.testing.assert_allclose(res.x, [1.5, -0.8], atol=1e-12)


def test_adaptive_damping_rejects_a_step_that_leaves_the_domain():
    """For b = 2 from b0 = 1 the Gauss-Newton step crosses b = 3, where the model
    cannot be evaluated: the adaptive solver damps it and converges; the plain
    Algorithm 2 (adaptive=False) stops with a message."""
    t = np.linspace(0.0, 1.0, 25)
    y = 1.5 * np.exp(2.0 * t)
    good = solve(Exponential(t, y, [1.0, 1.0]))
    assert good.converged, good.message
    np.testing.assert_allclose(good.x, [1.5, 2.0], atol=1e-9)
    plain = solve(Exponential(t, y, [1.0, 1.0]), SolverOptions(adaptive=False))
    assert not plain.converged
    assert plain.message.startswith("the step left the model's domain at iteration ")


class Rosenbrock(MeasurementModel):
    """Rosenbrock's curved valley as residuals ``(10 (x1 - x0^2), 1 - x0)`` and a zero
    row (one degree of freedom); the minimum at (1, 1)."""

    method = "rosenbrock"
    names = ("x0", "x1")
    channels = ("distance",)

    def __init__(self, x0):
        self.x0 = self.nominal = np.asarray(x0, float)
        self.row_channel = np.zeros(3, dtype=int)
        self.n_poses = 3

    def evaluate(self, x):
        r = np.array([-10.0 * (x[1] - x[0] ** 2), x[0] - 1.0, 0.0])
        W = np.array([[-20.0 * x[0], 10.0], [-1.0, 0.0], [0.0, 0.0]])
        return r, W


def test_the_damping_floor_gives_way_along_a_curved_valley():
    """From Rosenbrock's start (-1.2, 1) the steps swing and the damping relaxes by
    the gain ratio. Held at the damping last rejected for the rest of the round
    (``hold_damping``, the PM start fit's choice) it does not reach the minimum
    within 1000 iterations at fixed weights (it crawls along the valley: ~1e-8
    short of it after 1000 iterations, ~0.2 before rejected steps were retried by
    the parabola along them); giving way threefold after each well-predicted step,
    it does in 31 (39 before that retry). (With its sigma stated the first round is
    pooled, its weights follow the residual down, and the held fit converges too.)"""
    fixed = SolverOptions(weight_errors=False)
    res = solve(Rosenbrock([-1.2, 1.0]), fixed)
    assert res.converged, res.message
    assert res.iterations < 100
    np.testing.assert_allclose(res.x, [1.0, 1.0], atol=1e-9)
    held = solve(Rosenbrock([-1.2, 1.0]), replace(fixed, hold_damping=True))
    assert not held.converged
    assert held.message == "no convergence within 1000 iterations"
    stated = solve(Rosenbrock([-1.2, 1.0]), SolverOptions(sigma={"distance": 1.0},
                                                          hold_damping=True))
    assert stated.converged and "restart" not in stated.message, stated.message
    np.testing.assert_allclose(stated.x, [1.0, 1.0], atol=1e-9)


@pytest.mark.parametrize("b_true", [3.01, 3.2])
def test_a_minimum_beyond_the_domain_is_not_convergence(b_true):
    """The minimum (b = 3.01 or 3.2) lies where the model cannot be evaluated
    (b >= 3): every step towards it is rejected, the damping shrinks the step
    below epsilon at b -> 3, and that is a stall, not a minimum (a confident
    wrong answer: b = 3, a = 1.79 for 3.2, 5 of its std off). Within the
    domain the same data converge."""
    t = np.linspace(0.0, 1.0, 25)
    rng = np.random.default_rng(0)
    y = 1.5 * np.exp(b_true * t) + 1e-3 * rng.normal(size=25)
    res = solve(Exponential(t, y, [1.0, 1.0]))
    assert not res.converged
    assert res.message.startswith("stalled at iteration "), res.message
    inside = solve(Exponential(t, y, [1.0, 1.0], limit=4.0))
    assert inside.converged, inside.message
    assert abs(inside.x[1] - b_true) < 5 * math.sqrt(inside.covariance[1, 1])


# -- the scaled problem and its damped step (eqs. 47-49, 52) ---------------------------------
@pytest.mark.parametrize("rows", [12, 3, 2])
@pytest.mark.parametrize("per_row", [False, True])
def test_scaled_step_variance_and_condition(rows, per_row):
    rng = np.random.default_rng(rows)
    WA = rng.normal(size=(rows, 3)) * [1.0, 50.0, 0.01]
    r = rng.normal(size=rows)
    h = 1 / np.linalg.norm(WA, axis=0)
    g = rng.uniform(0.5, 2.0, size=rows) if per_row else 1.7
    G = np.broadcast_to(g, (rows,))
    A, b = WA * h * G[:, None], r * G
    F = Scaled(WA, {"distance": 1.0}, WA, h, g, r)
    assert F.cost == pytest.approx(0.5 * float(b @ b), rel=1e-12)
    sv = np.linalg.svd(A, compute_uv=False)
    assert F.s0 == pytest.approx(sv[0], rel=1e-10) and F.smin == pytest.approx(sv[-1], rel=1e-10)
    assert F.cond == pytest.approx(sv[0] / sv[-1], rel=1e-9)
    for lam2 in (0.0, 1e-4, 0.3):
        want = np.linalg.lstsq(np.vstack([A, math.sqrt(lam2) * np.eye(3)]),
                               np.r_[b, np.zeros(3)], rcond=None)[0]
        np.testing.assert_allclose(F.step(lam2), want, rtol=1e-8, atol=1e-12)
    z = rng.normal(size=3)
    assert F.scaled_norm(z) == pytest.approx(np.linalg.norm(A @ z), rel=1e-10)
    np.testing.assert_allclose(F.variance_scaled(), np.diag(np.linalg.pinv(A.T @ A)),
                               rtol=1e-7)


def test_scaled_singular_uses_the_pseudo_inverse():
    rng = np.random.default_rng(7)
    c = rng.normal(size=(10, 2))
    WA = np.column_stack([c[:, 0], c[:, 1], c[:, 0] + c[:, 1]])
    r = rng.normal(size=10)
    h = 1 / np.linalg.norm(WA, axis=0)
    F = Scaled(WA, {}, WA, h, 1.0, r)
    A = WA * h
    assert F.svd is not None and F.cond > 1e14
    np.testing.assert_allclose(F.step(0.0), np.linalg.pinv(A) @ r, rtol=1e-7, atol=1e-10)
    np.testing.assert_allclose(F.variance_scaled(), np.diag(np.linalg.pinv(A.T @ A, rcond=1e-15)),
                               rtol=1e-6)
    assert F.scaled_norm(np.ones(3)) == pytest.approx(np.linalg.norm(A @ np.ones(3)), rel=1e-8)


def test_masks(monkeypatch):
    monkeypatch.setattr(factored, "_MASKS", {})  # (filled by earlier tests: made anew here)
    tri, aug = masks(3)
    np.testing.assert_array_equal(tri, np.triu(np.ones((3, 4))))
    want = np.zeros((6, 4))
    want[3:, :3] = np.eye(3)
    np.testing.assert_array_equal(aug, want)
    assert masks(3)[0] is tri and tri.flags.f_contiguous and aug.flags.f_contiguous


# -- the final statistics' other paths -------------------------------------------------------
def test_ill_conditioned_columns_take_the_normal_matrix_pseudo_inverse():
    """Columns whose norms differ by 1e7: past the QR's safe range the covariance
    is the pseudo-inverse of the normal matrix (eq. 52 as written); it still is
    the covariance, and the condition number is that of the scaled matrix."""
    rng = np.random.default_rng(8)
    A = rng.normal(size=(30, 3)) * [1.0, 1e-7, 1e-3]
    y = A @ np.array([0.2, 3.0, -1.0]) + 1e-10 * rng.normal(size=30)
    res = solve(Linear(A, y))
    assert res.converged and res.n_identifiable == 3, res.message
    H = 1 / np.linalg.norm(A, axis=0)
    x, r, s2, _ = _ols(A * H, y)
    np.testing.assert_allclose(res.x, x * H, rtol=1e-7)
    cov = s2 * _t2(30 - 3) * np.outer(H, H) * np.linalg.inv((A * H).T @ (A * H))
    np.testing.assert_allclose(res.covariance, cov, rtol=1e-4)
    np.testing.assert_allclose(res.std, np.sqrt(np.diag(cov)), rtol=1e-4)
    assert res.condition_number == pytest.approx(np.linalg.cond(A * H), rel=1e-6)


@pytest.mark.parametrize("opts", [dict(recheck=False), dict(scale_columns=False),
                                  dict(recheck=False, scale_columns=False)])
def test_per_channel_covariance_without_a_factor_to_reuse(opts):
    """Without the recheck's triangle (or with unscaled columns) the final
    covariance is a QR of its own: the same (W^T L W)^-1, L from the final sigma
    (with its own uncertainty); the condition number that of the weights of eq. 51."""
    model, A, y, ch = _two_channels()
    res = solve(model, SolverOptions(**opts))
    assert res.converged, res.message
    wc = 1 / np.array([res.sigma[n] ** 2 * _t2(res.sigma_dof[n]) for n in model.channels])[ch]
    np.testing.assert_allclose(res.covariance, np.linalg.inv(A.T @ (A * wc[:, None])), rtol=1e-8)
    w = 1 / np.array([res.sigma["distance"], res.sigma["tilt"]])[ch] ** 2
    H = 1 / np.linalg.norm(A, axis=0) if opts.get("scale_columns", True) else np.ones(3)
    assert res.condition_number == pytest.approx(np.linalg.cond(A * H * np.sqrt(w)[:, None]),
                                                  rel=1e-8)


def test_status_carries_the_columns_figures():
    """Each status names its parameter and carries |R[j, j]| of the unit, weighted
    columns and the weighted column norm, identifiable or not."""
    rng = np.random.default_rng(1)
    c0, c1, c3 = rng.normal(size=(3, 25))
    A = np.column_stack([c0, c1, 2 * c0 - c1, np.zeros(25), 10 * c3])
    y = A @ np.array([0.4, -0.7, 0.0, 0.0, 0.05]) + 1e-3 * rng.normal(size=25)
    res = solve(Linear(A, y))
    s = res.sigma["distance"]
    norms = np.linalg.norm(A, axis=0) / s
    assert [st.name for st in res.status] == list(res.names)
    np.testing.assert_allclose([st.column_norm for st in res.status], norms, rtol=1e-9)
    keep = [0, 1, 4]
    d = np.abs(np.diag(np.linalg.qr(A[:, keep] / np.linalg.norm(A[:, keep], axis=0))[1]))
    np.testing.assert_allclose([res.status[j].r_diag for j in keep], d, rtol=1e-9)
    assert res.status[2].r_diag < 1e-8 and res.status[3].r_diag == 0.0
    assert [st.influences_model for st in res.status] == [False, False, True, False, False]
    assert res.method == "linear"
    # unweighted (weight_errors=False): the same figures without the 1/sigma
    un = solve(Linear(A, y), SolverOptions(weight_errors=False))
    np.testing.assert_allclose([st.column_norm for st in un.status], norms * s, rtol=1e-9)


def test_channel_without_rows():
    """A channel of the method that this data set has no rows of: no RMS, no
    weight, the other channel's answer unchanged."""
    A, y, _ = _linear()
    res = solve(Linear(A, y, channels=("distance", "tilt")))
    x, r, s2, cov = _ols(A, y)
    np.testing.assert_allclose(res.x, x, rtol=1e-9)
    assert math.isnan(res.residual_rms["tilt"])
    assert res.residual_rms["distance"] == pytest.approx(math.sqrt(r @ r / 30), rel=1e-9)
    assert res.sigma["distance"] == pytest.approx(math.sqrt(s2), rel=1e-9)


def test_wall_time_is_the_solve_s():
    import time

    A, y, _ = _linear()
    t0 = time.perf_counter()
    res = solve(Linear(A, y))
    assert 0 < res.wall_time <= time.perf_counter() - t0


def test_history_variance_and_cost_of_every_iteration():
    """Iteration 1 runs with L = I and records the pooled sigma of its step's
    residual (eq. 51): variance sigma_1^2 (W^T W)^-1; without error weighting
    L = I throughout."""
    A, y, _ = _linear()
    res = solve(Linear(A, y))
    h0 = res.history[0]
    np.testing.assert_allclose(h0.variance, h0.sigma["distance"] ** 2
                               * np.diag(np.linalg.inv(A.T @ A)), rtol=1e-9)
    assert all(isinstance(h.cost, float) for h in res.history)
    r1 = y - A @ res.history[-2].x
    assert res.history[-1].cost == pytest.approx(0.5 * float(r1 @ r1)
                                                 / res.history[-2].sigma["distance"] ** 2,
                                                 rel=1e-9)
    model, A2, y2, ch = _two_channels()
    un = solve(model, SolverOptions(weight_errors=False))
    for h, x_before in zip(un.history, [np.zeros(3)] + [h.x for h in un.history[:-1]]):
        rb = y2 - A2 @ x_before
        assert h.cost == pytest.approx(0.5 * float(rb @ rb), rel=1e-9)
    last = un.history[-1]
    np.testing.assert_allclose(last.variance, last.sigma["distance"] ** 2
                               * np.diag(np.linalg.inv(A2.T @ A2)), rtol=1e-9)


def test_known_sigma_far_from_the_data_is_still_used():
    """Known sigmas are the trace's: never re-estimated, even where the residual
    disagrees tenfold."""
    model, A, y, ch = _two_channels()
    sig = {"distance": 1e-3, "tilt": 0.3}
    res = solve(model, SolverOptions(sigma=sig))
    w = 1 / np.array([1e-3, 0.3])[ch] ** 2
    x, cov = _wls(A, y, w)
    np.testing.assert_allclose(res.x, x, rtol=1e-10)
    np.testing.assert_allclose(res.covariance, cov, rtol=1e-8)
    assert all(h.sigma == sig for h in res.history)


def test_two_channel_rounds():
    """The per-channel rounds stop when the weights settle (no channel's sigma
    changes by 5 %), well before the limit of six rounds."""
    model, A, y, ch = _two_channels()
    res = solve(model)
    assert 1 <= res.rounds < 5, [h.step for h in res.history]


def test_start_values_given_as_integers():
    A, y, _ = _linear()
    m = Linear(A, y)
    m.x0 = [0, 0, 0]
    res = solve(m)
    np.testing.assert_allclose(res.x, _ols(A, y)[0], rtol=1e-9)
    assert res.x0.dtype == float


def test_observation_matrix_not_finite_at_the_start():
    A, y, _ = _linear()
    Ab = A.copy()
    Ab[3, 1] = np.inf
    with np.errstate(invalid="ignore"), pytest.raises(CalibrationError,
                       match="^the model gives non-finite values at the start parameters$"):
        solve(Linear(Ab, y))


def test_too_few_rows_counts_rows_per_pose():
    A, y, _ = _linear(rows=2)
    m = Linear(A, y)
    m.n_poses = 1  # two rows per pose
    with pytest.raises(CalibrationError, match=r"^1 poses give 2 equations for up to 3 parameters; "
                                               r"at least 2 poses are needed \(recommended 8, eq. 60\)$"):
        solve(m)


def test_dependent_column_dropped_at_the_solution_refits_the_others():
    """A column that is a strong column plus a part below kappa times the residual:
    dependent at the solution, back to its start value, and the others refitted
    with it there (two channels of equal noise: one sigma, as one channel)."""
    rng = np.random.default_rng(9)
    Q, _ = np.linalg.qr(rng.normal(size=(40, 4)))
    strong = rng.normal(size=(40, 2))
    strong -= Q[:, 2:] @ (Q[:, 2:].T @ strong)
    A = np.column_stack([strong, 0.5 * strong[:, 0] + 1.5e-3 * Q[:, 2]])
    y = A @ np.array([0.3, -0.2, 0.0]) + 1e-3 * Q[:, 3]
    ch = np.arange(40) % 2
    for model in (Linear(A, y, x0=[0.0, 0.0, 0.1]),
                  Linear(A, y, x0=[0.0, 0.0, 0.1], channel=ch, channels=("distance", "tilt"))):
        res = solve(model)
        assert res.converged, res.message
        assert res.status[2].label == ident.INFLUENCES and res.x[2] == 0.1
        used = res.history[-1].sigma
        w = 1 / np.array([used[c] for c in model.channels])[model.row_channel] ** 2
        np.testing.assert_allclose(res.x[:2], _wls(A[:, :2], y - 0.1 * A[:, 2], w)[0], rtol=1e-9)
        # sigma per channel: the leverages of the calibrated columns only
        r = y - A @ res.x
        for c, want in enumerate(_channel_sigmas(A[:, :2], r, model.row_channel, w)):
            assert res.sigma[model.channels[c]] == pytest.approx(want, rel=1e-9)


def test_fixed_parameter_stays_without_the_recheck():
    A, y, truth = _linear()
    res = solve(Linear(A, y, x0=[0.0, 0.0, 0.5]), SolverOptions(fixed=("x2",), recheck=False))
    assert res.x[2] == 0.5 and not res.status[2].identifiable and np.isnan(res.std[2])
    np.testing.assert_allclose(res.x[:2], _ols(A[:, :2], y - 0.5 * A[:, 2])[0], rtol=1e-9)


class Twinned(Linear):
    """A model whose rows are constraints among predictions (as self-calibration):
    its structural identifiability is judged on a twin whose data the start
    values explain exactly, where x2's column is zero."""

    def consistent_twin(self, x):
        B = self.A.copy()
        B[:, 2] = 0.0
        return Linear(B, B @ np.asarray(x, float))


def test_structural_check_on_the_consistent_twin():
    A, y, truth = _linear()
    start = [0.0, 0.0, truth[2]]  # x2 at its value: the others fit to the noise
    res = solve(Twinned(A, y, x0=start))
    assert res.converged, res.message
    assert not res.status[2].identifiable and res.x[2] == truth[2]
    np.testing.assert_allclose(res.x[:2], _ols(A[:, :2], y - truth[2] * A[:, 2])[0], rtol=1e-9)
    # left out at the start, independent at the solution: not calibrated, and a
    # wrong start value would bias the others (it influences the model)
    st = res.status[2]
    assert st.name == "x2" and st.influences_model and st.label == ident.INFLUENCES
    assert st.column_norm == pytest.approx(np.linalg.norm(A[:, 2]) / res.sigma["distance"],
                                           rel=1e-9)
    assert st.r_diag == pytest.approx(np.abs(np.linalg.qr(A / np.linalg.norm(A, axis=0))[1][2, 2]),
                                      rel=1e-9)
    assert res.nfev == res.iterations + 1  # the twin's evaluation counts
    fx = solve(Twinned(A, y), SolverOptions(fixed=("x0",), recheck=False))
    assert [s.identifiable for s in fx.status] == [False, True, False] and fx.x[0] == 0.0


def _cov_accurate(A, w):
    """``(A^T L A)^-1``, ``L = diag(w)``, from the QR of the scaled columns
    (accurate where the normal matrix is not)."""
    H = 1 / np.linalg.norm(A, axis=0)
    R = np.linalg.qr(A * H * np.sqrt(w)[:, None])[1]
    Ri = np.linalg.inv(R)
    return np.outer(H, H) * (Ri @ Ri.T)


@pytest.mark.parametrize("case", ["one channel", "two channels", "two channels, no recheck"])
def test_covariance_is_accurate_with_columns_far_apart(case):
    """Column norms 1e3 apart and two nearly parallel columns (condition ~1e3 after
    scaling): the normal matrix loses ~12 digits, a QR of the scaled matrix ~3.
    Each of the covariance's QR paths (the last iteration's factor, the
    recheck's triangle, a QR of its own) keeps 1e-11."""
    rng = np.random.default_rng(10)
    c = rng.normal(size=(60, 3))
    A = np.column_stack([c[:, 0], 300 * (c[:, 0] + 0.002 * c[:, 1]), 0.3 * c[:, 2]])
    ch = np.repeat([0, 1], 30)
    y = A @ np.array([0.5, -3e-3, 2.0]) + np.where(ch == 0, 1e-5, 3e-4) * rng.normal(size=60)
    if case == "one channel":
        res = solve(Linear(A, y))
    else:
        res = solve(Linear(A, y, channel=ch, channels=("distance", "tilt")),
                    SolverOptions(recheck=case == "two channels"))
    assert res.converged, res.message
    # each estimated sigma with its own uncertainty (Student's t, its degrees of freedom)
    var = np.array([res.sigma[c] ** 2 * _t2(res.sigma_dof[c]) for c in res.sigma])
    w = 1 / var[ch if len(res.sigma) == 2 else 0 * ch]
    want = _cov_accurate(A, w)
    np.testing.assert_allclose(res.covariance, want, rtol=1e-11)
    # the test can fail: the normal matrix's inverse is off by far more
    rough = np.linalg.pinv(A.T @ (A * w[:, None]))
    assert np.max(np.abs(rough - want) / np.abs(want)) > 1e-10


def test_a_fixed_parameter_reports_its_columns_influence():
    """A fixed parameter is labelled fixed, and whether the measurements depend on
    it: a strong column influences the model (a wrong value biases the others;
    it was reported "no influence" before), a zero column does not."""
    rng = np.random.default_rng(2)
    c0, c1, c2 = rng.normal(size=(3, 25))
    A = np.column_stack([c0, c1, 5 * c2, np.zeros(25)])
    y = A @ np.array([0.4, -0.7, 0.0, 0.0]) + 1e-3 * rng.normal(size=25)
    res = solve(Linear(A, y), SolverOptions(fixed=("x2", "x3")))
    st = {s.name: s for s in res.status}
    assert [st[n].identifiable for n in res.names] == [True, True, False, False]
    assert st["x2"].fixed and st["x2"].influences_model
    assert st["x2"].label == f"{ident.FIXED}, {ident.INFLUENCES}"
    assert st["x3"].fixed and not st["x3"].influences_model
    assert st["x3"].label == f"{ident.FIXED}, {ident.NO_INFLUENCE}"
    assert not st["x0"].fixed and st["x0"].label == ident.IDENTIFIABLE


def test_an_exact_fit_shares_one_sigma_and_runs_no_round_for_round_off():
    """Noise-free sm-full-pose (four channels): every residual at round-off. The
    per-channel estimates then differ only by each channel's arithmetic (x 1.1e-13 m
    against z's 1e-14 floor before): reweighting by them ran a second round that moved
    nothing. Now one sigma (eq. 51 over all rows) for every channel, no degrees of
    freedom (it estimates no noise, so no t factor in the std), one round."""
    from tests.calibration.helpers import dataset
    from calibration.solver.weighting import ROUNDOFF_SIGMA

    model, truth = dataset("sm-full-pose", seed=0, count=30)
    res = solve(model)
    assert res.converged, res.message
    assert max(res.residual_rms.values()) < ROUNDOFF_SIGMA
    assert len(set(res.sigma.values())) == 1, res.sigma
    r = res.residual
    s = max(math.sqrt(float(r @ r) / (len(r) - res.n_identifiable)), 1e-14)
    assert res.sigma[model.channels[0]] == pytest.approx(s, rel=1e-9)
    assert res.sigma_dof == {}
    assert res.rounds == 1
    ident = np.array([st.identifiable for st in res.status])
    W = model.evaluate(res.x)[1][:, ident]
    std = s * np.sqrt(np.diag(np.linalg.inv(W.T @ W)))
    np.testing.assert_allclose(res.std[ident], std, rtol=1e-6)
    np.testing.assert_allclose(res.x[ident], truth[ident], atol=1e-9)


def test_settles_only_on_fast_contraction_and_a_predicted_step_below_epsilon():
    settles = step.Stepping._settles
    assert settles(2e-7, [1e-1, 2e-3], 1e-10)  # next ~ 2e-7 * 1e-4
    assert not settles(2e-7, [2e-3], 1e-10)  # one step before it: no rate yet
    assert not settles(2e-7, [1e-3, 2e-3], 1e-10)  # the step before did not contract
    assert not settles(1e-6, [1e-1, 1e-3], 1e-10)  # next ~ 1e-9
    assert not settles(2e-5, [1e0, 1e-1], 1e-10)  # above sqrt(epsilon)
    assert not settles(2e-7, [1e-1, 0.0], 1e-10)


def test_the_condition_number_is_judged_and_reported_as_the_singular_values_give_it():
    """``Scaled.cond_below`` decides as the condition number does (from the bound
    ||R||_F ||R^-1||_F where that decides, else the singular values), and a result
    whose condition number was deferred to the last iteration's triangle reports the
    singular values' ratio when read, through pickling and ``replace`` alike."""
    rng = np.random.default_rng(3)
    for k in range(40):
        A = rng.normal(size=(30, 6)) * np.logspace(0, rng.uniform(0, 9), 6)
        F = Scaled(A, None, A, np.ones(6), 1.0, rng.normal(size=30))
        cond = np.linalg.cond(A)
        for limit in (cond * 0.999, cond * 1.001, cond * 3, math.sqrt(6) * cond * 1.01):
            assert F.cond_below(limit) == (cond < limit), (k, limit / cond)
    import pickle

    A = rng.normal(size=(40, 5)) * np.array([1.0, 10.0, 1e3, 0.1, 5.0])
    model = Linear(A, A @ np.arange(1.0, 6.0) + 1e-3 * rng.normal(size=40))
    res = solve(model)
    assert isinstance(res._condition, np.ndarray)  # not formed by the solve itself
    H = 1.0 / np.linalg.norm(A, axis=0)
    expect = np.linalg.cond(A * H)
    for r in (pickle.loads(pickle.dumps(res)), replace(res, nfev=1), res):
        assert r.condition_number == pytest.approx(expect, rel=1e-9)
