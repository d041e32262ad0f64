"""Noise-free recovery of the truth for every SM method, and the ablation of
the report's section 7.6 (with what happens here where it differs)."""
import numpy as np
import pytest

from calibration import planning, simulate
from calibration.methods.sm_distance_tilt import DistanceTilt, reframe_nominal
from calibration.robots import get_robot
from calibration.solver import SolverOptions, solve
from tests.calibration.helpers import dataset

SM = get_robot("agebot-sm")


@pytest.mark.parametrize("method,residual", [
    ("sm-full-pose", None), ("sm-distance", "plain"), ("sm-distance", "squared"),
    ("sm-self-redundancy", None), ("sm-plane", None), ("sm-distance-tilt", "plain"),
    ("sm-distance-tilt", "squared")])
def test_noise_free_converges_to_truth(method, residual):
    model, truth = dataset(method, seed=11)
    if residual:
        model.residual = residual
    res = solve(model)
    assert res.converged, res.message
    ident = np.array([s.identifiable for s in res.status])
    err = np.abs(res.x - truth)[ident]
    assert err.max() < 1e-9, dict(zip(np.array(res.names)[ident], err))
    assert res.iterations <= 100


def test_distance_tilt_frame_values_match_brief():
    """With the report's X_Db = (0.5, 1, 0.8): theta0 = atan2(-0.6, -0.3),
    a0 = 0.67082, q1_off = -0.6 (the true base offset is rounded in the report)."""
    qb = SM.ik([0.5, 1.0, 0.8, 0.0], SM.true, elbow=-1)
    framed = reframe_nominal(SM, SM.true, qb)
    assert framed[SM.index("theta0")] == pytest.approx(np.arctan2(-0.6, -0.3), abs=1e-4)
    assert framed[SM.index("a0")] == pytest.approx(0.67082, abs=1e-4)
    assert framed[SM.index("q1_off")] == pytest.approx(-0.6, abs=1e-9)


def test_influencing_parameter_at_wrong_nominal_biases_the_others():
    """7.3: L4 left at its nominal: the fit satisfies the constraint but the
    other parameters are wrong (report Fig. 21)."""
    model, truth = dataset("sm-self-redundancy", seed=12, known=())
    res = solve(model)
    assert res.converged
    ident = np.array([s.identifiable for s in res.status])
    assert np.abs(res.x - truth)[ident].max() > 1e-4


def test_no_influence_parameter_at_wrong_nominal_does_not_bias():
    model, truth = dataset("sm-distance", seed=13)
    res = solve(model)
    ident = np.array([s.identifiable for s in res.status])
    assert np.abs(res.x - truth)[ident].max() < 1e-9
    assert not ident[SM.index("theta0")]
    assert res.x[SM.index("theta0")] == SM.nominal[SM.index("theta0")]


def _dt_problem(seed, box):
    qb = SM.ik([0.5, 1.0, 0.8, 0.0], SM.nominal, elbow=-1)
    start = reframe_nominal(SM, SM.nominal, qb)
    plan = planning.sample_poses(SM, start, box, 33, np.random.default_rng(seed),
                                 ik_options={"elbow": -1})
    meas = simulate.measure("sm-distance-tilt", SM, SM.true, plan.qm, reference_qm=qb)
    truth = reframe_nominal(SM, SM.true, qb)
    return (lambda: DistanceTilt(SM, plan.qm, meas, SM.nominal, reference_qm=qb,
                                 residual="squared")), truth


REPORT = dict(adaptive=False, max_iter=4000)  # the report's plain Algorithm 2


def test_ablation_well_spread_poses():
    """The report's box of 7.5: about 10 iterations with H, L and damping."""
    make, truth = _dt_problem(0, planning.box_array(SM, planning.SM_BOX_7_5))
    res = solve(make(), SolverOptions(**REPORT))
    assert res.converged and res.iterations <= 12
    assert np.abs(res.x - truth).max() < 1e-9


def test_ablation_badly_chosen_poses():
    """Poses in a small box (condition number ~1e3-1e4):
    - with H, L, damping: converges in about 10 iterations;
    - without L (L = I): the damping then dominates the weak directions and it
      takes well over a thousand iterations (report: ~500);
    - without H or without damping the report saw failure / wrong values from
      the normal equations; here the step is solved by QR of the augmented
      system, and both still converge to the truth.
    """
    box = np.array([[-0.05, 0.05], [-0.05, 0.05], [-0.1, 0.1], [-0.05, 0.05]])
    make, truth = _dt_problem(0, box)
    full = solve(make(), SolverOptions(**REPORT))
    assert full.converged and full.iterations <= 12
    no_l = solve(make(), SolverOptions(weight_errors=False, **REPORT))
    assert no_l.iterations > 50 * full.iterations
    for opts in (dict(scale_columns=False), dict(damping=0.0)):
        res = solve(make(), SolverOptions(**opts, **REPORT))
        assert res.converged
        assert np.abs(res.x - truth).max() < 1e-8


@pytest.mark.parametrize("method", ["sm-distance", "sm-distance-tilt"])
def test_a_zero_offset_biases_the_exact_model_not_the_reading_one(method):
    """Every distance 30 um off (the draw-wire zeroed on one noisy reading): the
    report's model, which takes the zero as exact, comes out wrong; with the zero
    as a reading (``distance_off`` calibrated) the truth is recovered exactly."""
    exact, truth = dataset(method, seed=11, distance_off=3e-5)
    res = solve(exact)
    ident = np.array([s.identifiable for s in res.status])
    assert not res.converged or np.abs(res.x - truth)[ident].max() > 1e-5
    model, truth = dataset(method, seed=11, distance_zero="reading", distance_off=3e-5)
    res = solve(model)
    assert res.converged, res.message
    ident = np.array([s.identifiable for s in res.status])
    assert np.abs(res.x - truth)[ident].max() < 1e-9
    assert res.x[-1] == pytest.approx(3e-5, abs=1e-12)


def test_the_adaptive_damping_does_not_swing_in_a_curved_valley():
    """sm-distance (plain residual), 100 poses in the report's box of 7.1: the
    Gauss-Newton steps overshoot along a curved valley, and the damping swung
    between a rejected and an accepted value on every iteration (106 iterations,
    210 evaluations; scipy's trf needs 18). Relaxed by the gain ratio once it
    swings, the same truth in a fraction of them; the plain Algorithm 2 is
    unchanged by it."""
    from calibration.methods.sm_distance import Distance

    off = np.r_[SM.base_offset(SM.true), 0.0]
    ref = SM.ik(np.array([1.0, 1.0, 0.0, 0.2]) + off, SM.true)
    plan = planning.sample_poses(SM, SM.nominal,
                                 planning.box_array(SM, planning.SM_BOX_7_1, off), 100,
                                 np.random.default_rng([1, 1]))
    meas = simulate.measure("sm-distance", SM, SM.true, plan.qm, reference_qm=ref)
    res = solve(Distance(SM, plan.qm, meas, SM.nominal, reference_qm=ref))
    assert res.converged, res.message
    ident = np.array([s.identifiable for s in res.status])
    assert np.abs(res.x - SM.true)[ident].max() < 1e-9
    assert res.iterations <= 20 and res.nfev <= 25, (res.iterations, res.nfev)


NOISE = {"distance": 1e-5, "tilt": 1e-4, "position": 1e-5, "orientation": 1e-4}


@pytest.mark.parametrize("method", ["sm-full-pose", "sm-distance", "sm-distance-tilt"])
def test_a_settled_last_step_is_followed_by_a_step_below_epsilon(method):
    """Where the steps contract fast enough the last is taken without evaluating
    the model after it (the residual predicted, one evaluation fewer): the
    undamped step from that solution at its final weights must then be below
    epsilon, and the predicted residual the model's own there."""
    settled = 0
    for seed in range(4):
        for noise in (None, NOISE):
            model, _ = dataset(method, seed=seed, count=30, noise=noise)
            res = solve(model)
            assert res.converged, res.message
            if "predicted for the step after the last" not in res.message:
                assert res.history[-1].step < 1e-10
                continue
            settled += 1
            r, W = model.evaluate(res.x)
            act = np.array([s.identifiable for s in res.status])
            w = 1.0 / np.array([res.sigma[ch] for ch in model.channels])[model.row_channel]
            gn = np.linalg.lstsq(W[:, act] * w[:, None], r * w, rcond=None)[0]
            assert np.abs(gn).max() < 1e-10, (seed, noise, np.abs(gn).max())
            np.testing.assert_allclose(r, res.residual, rtol=0, atol=1e-12)
    assert settled >= 3  # (the rule is exercised: 4-8 of these fits settle)


@pytest.mark.parametrize("seed,count", [(1, 8), (1, 17), (8, 8)])
def test_no_predicted_last_step_while_the_damping_holds_back_a_direction(seed, count):
    """Without error weighting (the pooled sigma's weights would dwarf it) the
    damping can hold back a weak direction while the step's largest component
    falls fast: predicting the next step from that fall alone ended these fits
    with a next step of 1.0e-10, 1.6e-10 and 2.3e-10. The part the damping held
    back is now added to the prediction."""
    model, _ = dataset("sm-position", seed=seed, count=count, noise={"position": 1e-5})
    res = solve(model, SolverOptions(weight_errors=False))
    assert res.converged, res.message
    r, W = model.evaluate(res.x)
    act = np.array([s.identifiable for s in res.status])
    gn = np.linalg.lstsq(W[:, act], r, rcond=None)[0]
    assert np.abs(gn).max() < 1e-10, np.abs(gn).max()


def _distance_100(noise):
    """sm-distance at 100 poses drawn as bench/_common.py's seed 1 draws them: from
    the nominal, undamped first steps (a sigma stated, the weights far above lambda)
    lead the fit into a local minimum (residual RMS 1.6 mm)."""
    from calibration.methods.sm_distance import Distance

    T, N = SM.true, SM.nominal
    off = np.r_[SM.base_offset(T), 0.0]
    ref = SM.ik(np.array([1.0, 1.0, 0.0, 0.2]) + off, T)
    plan = planning.sample_poses(SM, N, planning.box_array(SM, planning.SM_BOX_7_1, off), 100,
                                 np.random.default_rng([1, 1]))
    meas = simulate.measure("sm-distance", SM, T, plan.qm, reference_qm=ref,
                            noise=None if noise is None else {"distance": noise},
                            rng=np.random.default_rng([1, 1, 7]))
    return Distance(SM, plan.qm, meas, N, reference_qm=ref)


@pytest.mark.parametrize("noise", [None, 1e-4])
def test_a_stated_noise_weighs_the_rows_from_the_pooled_solution_on(noise, monkeypatch):
    """Weighted by the stated sigma from the first step, this fit ends in a local
    minimum (residual RMS 1.6 mm, 16 times the stated noise). Its first round pooled,
    as the report's Algorithm 2 runs (L = I, then eq. 51's one sigma), it reaches
    the truth with no restart, and its statistics are those of the stated sigma.
    Where the first fit misses (here the two paths swapped), the restart runs the
    other and keeps the lower minimum."""
    from calibration.solver import rounds

    model = _distance_100(noise)
    opts = SolverOptions(sigma={"distance": 1e-4})
    res = solve(model, opts)
    assert res.converged and "restart" not in res.message, res.message
    assert res.sigma == {"distance": 1e-4} and res.sigma_known
    rms = float(np.sqrt(np.mean(res.residual ** 2)))
    assert rms < (1e-12 if noise is None else 2e-4), rms
    active = np.array([s.identifiable for s in res.status])
    err = np.abs(res.x - SM.true)[active]
    assert np.all(err < (1e-9 if noise is None else 5 * res.std[active])), err
    # the covariance at the stated sigma (eq. 52), not at the pooled round's
    W = model.evaluate(res.x)[1][:, active]
    cov = 1e-4 ** 2 * np.linalg.inv(W.T @ W)
    np.testing.assert_allclose(res.std[active], np.sqrt(np.diag(cov)), rtol=1e-6)
    # and so is every iteration's record, the pooled round's too: the first at x0
    assert all(h.sigma == {"distance": 1e-4} for h in res.history)
    r0, W0 = model.evaluate(model.x0)
    h0 = res.history[0]
    on = np.isfinite(h0.variance)
    np.testing.assert_allclose(h0.variance[on], 1e-4 ** 2 * np.diag(np.linalg.inv(
        W0[:, on].T @ W0[:, on])), rtol=1e-6)
    assert h0.cost == pytest.approx(0.5 * float(r0 @ r0) / 1e-4 ** 2, rel=1e-12)
    Wn = W0[:, on] / np.linalg.norm(W0[:, on], axis=0)
    assert h0.condition_number == pytest.approx(np.linalg.cond(Wn), rel=1e-8)
    # weighted by the stated sigma from the first step: the local minimum
    first = rounds._solve(model, opts, None, 0.0, other_path=True)[0]
    assert first.converged and np.sqrt(np.mean(first.residual ** 2)) > 1e-3
    # the paths swapped: the first fit misses, and the restart's minimum is kept
    orig = rounds._solve
    monkeypatch.setattr(rounds, "_solve", lambda m, o, cb, t, other_path=False:
                        orig(m, o, cb, t, not other_path))
    swapped = solve(model, opts)
    assert swapped.converged and "after a restart: the first fit ended at chi-square" in \
        swapped.message, swapped.message
    np.testing.assert_allclose(swapped.x, res.x, rtol=0, atol=1e-9)
    assert swapped.nfev == first.nfev + res.nfev


def test_a_fit_that_explains_its_readings_is_not_restarted():
    """A fit whose noise is stated right is not restarted; one stated ten times too
    small is, ends no lower, and keeps the first fit (its evaluations counted)."""
    from calibration.solver import rounds

    model45 = dataset("sm-distance", seed=3, noise={"distance": 1e-4})[0]
    res = solve(model45, SolverOptions(sigma={"distance": 1e-4}))
    assert res.converged and "restart" not in res.message
    tight = solve(model45, SolverOptions(sigma={"distance": 1e-5}))
    assert tight.converged and "ended no lower" in tight.message, tight.message
    old = rounds.RESTART_ALPHA
    try:
        rounds.RESTART_ALPHA = 0.0
        plain = solve(model45, SolverOptions(sigma={"distance": 1e-5}))
    finally:
        rounds.RESTART_ALPHA = old
    assert np.array_equal(plain.x, tight.x) and tight.nfev > plain.nfev
