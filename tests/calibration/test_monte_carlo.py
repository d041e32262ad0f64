"""Noisy traces, Monte Carlo: the reported std is honest.

For the plain distance residual (noise uniform over poses) the normalized
errors (error / reported std) have an RMS near 1 and the reported std is
close to the Cramer-Rao bound. For the report's squared residual the rows'
noise is 2 D sigma, not uniform, so eq. 51's single sigma mis-states the
errors: this is why plain is the default (docs/methods.md).
"""
import numpy as np
import pytest

from calibration.solver import SolverOptions, solve
from tests.calibration.helpers import dataset

RUNS = 300
NOISE = {"distance": 2e-4, "tilt": 2e-4}


def _monte_carlo(residual):
    normalized, stds, errors = [], [], []
    truth = crb = None
    for seed in range(RUNS):
        model, truth = dataset("sm-distance-tilt", seed=1000 + seed, noise=NOISE)
        if seed == 0:
            fixed_qm = model.qm
        # same poses every run, fresh noise: the scatter is then comparable to one std
        model.qm = fixed_qm
        from calibration.simulate import measure
        from calibration.robots import get_robot

        sm = get_robot("agebot-sm")
        meas = measure("sm-distance-tilt", sm, sm.true, fixed_qm, reference_qm=model.reference_qm,
                       noise=NOISE, rng=np.random.default_rng(seed))
        model.D_m, model.phi_m = meas["distance"], meas["tilt"]
        model.residual = residual
        res = solve(model, SolverOptions())
        assert res.converged
        if crb is None:  # Cramer-Rao bound at the truth for the known noise
            _, W = model.evaluate(truth)
            model.residual = "plain"
            _, Wp = model.evaluate(truth)
            w = np.where(model.row_channel == 0, 1 / NOISE["distance"] ** 2, 1 / NOISE["tilt"] ** 2)
            crb = np.sqrt(np.diag(np.linalg.inv(Wp.T @ (Wp * w[:, None]))))
        errors.append(res.x - truth)
        stds.append(res.std)
        normalized.append((res.x - truth) / res.std)
    return np.array(normalized), np.array(stds), np.array(errors), crb


def test_plain_residual_reports_honest_std():
    z, stds, errors, crb = _monte_carlo("plain")
    rms = np.sqrt(np.mean(z ** 2, axis=0))
    assert np.all((rms > 0.8) & (rms < 1.2)), rms
    ratio = np.median(stds, axis=0) / crb
    assert np.all((ratio > 0.8) & (ratio < 1.25)), ratio
    scatter = errors.std(axis=0) / crb
    assert np.all((scatter > 0.8) & (scatter < 1.25)), scatter


@pytest.mark.heavy
def test_squared_residual_std_does_not_match_scatter():
    z_sq, *_ = _monte_carlo("squared")
    z_pl, *_ = _monte_carlo("plain")
    dev_sq = np.abs(np.sqrt(np.mean(z_sq ** 2, axis=0)) - 1).max()
    dev_pl = np.abs(np.sqrt(np.mean(z_pl ** 2, axis=0)) - 1).max()
    assert dev_sq > 0.3 and dev_sq > 2 * dev_pl


# -- realistic noise, drawn robots (tests/calibration/montecarlo.py) ---------------------
# The targets are for the true figures: RMS of error/std in 0.9-1.1, coverage of
# 2 std in 92-98 %. The errors within a run are correlated, so the runs are the
# samples: each figure's standard error comes from the scatter of the runs' own
# figures (montecarlo.Figures.rms_se, coverage2_se; about 0.03-0.06 and 1 % at
# these run counts), and the sample must lie within the target band widened by
# three of them. bench/bench_montecarlo.py prints the figures over more runs.
# Fits the station refuses (residual above 3 times the noise) are counted and
# must stay rare.
REALISTIC_RUNS = {"sm-distance-tilt": 100, "sm-distance": 80, "pm-fk": 120, "pm-tilt": 40}


@pytest.mark.slow
@pytest.mark.parametrize("method", list(REALISTIC_RUNS))
def test_std_is_honest_at_realistic_noise_on_drawn_robots(method):
    from tests.calibration.montecarlo import monte_carlo

    runs = REALISTIC_RUNS[method]
    f = monte_carlo(method, runs, seed=1)
    figures = (f"RMS err/std {f.rms:.3f} +- {f.rms_se:.3f}, within 2 std "
               f"{f.coverage2:.3f} +- {f.coverage2_se:.3f}, std/CRB {f.std_over_crb:.3f}, "
               f"{f.failed} of {runs} refused")
    print(f"{method}: {figures}")
    assert f.failed <= 0.2 * runs, figures
    assert 0.9 - 3 * f.rms_se <= f.rms <= 1.1 + 3 * f.rms_se, figures
    assert 0.92 - 3 * f.coverage2_se <= f.coverage2 <= 0.98 + 3 * f.coverage2_se, figures
    assert 0.9 <= f.std_over_crb <= 1.1, figures
    if method == "pm-tilt":   # the heading it does not identify: its stated std is honest too
        h = (f"heading error/std RMS {f.heading_rms:.3f} +- {f.heading_rms_se:.3f}, within 2 "
             f"std {f.heading_coverage2:.3f} over {f.heading.size} runs")
        assert f.heading.size == runs - f.failed, h
        assert 0.9 - 3 * f.heading_rms_se <= f.heading_rms <= 1.1 + 3 * f.heading_rms_se, h
        assert f.heading_coverage2 >= 0.85, h
