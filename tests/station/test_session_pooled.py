"""Is the reported std of a whole session honest? Pooled over simulator seeds and arms.

One session's parameters are one draw: a bound on them (the fast tests in
``test_session.py`` and ``test_serial_session.py``: every parameter within the
1 % family bound of its count, 3.4-4.2 std for 14, 3.6-3.9 for 27; a session is not
bit-identical when rerun, so 3 std on each would fail an honest one 4-7 % of
the time) catches gross errors and biases of ~4 std, not a std that is 20 %
optimistic. Here whole
simulated sessions (``station.simulation.sessions``: the simulator in its own process,
one unattended session, the result against the truth in the session's own
terms) are pooled over arms drawn around the nominal (``draw_truth``) with the
devices' noise (distance 1e-5 m, tilt 1.7e-4 rad per reading), one seed per
session for the arm, the simulator's noise and the plan.

Targets (issue 16): RMS of error/std in 0.9-1.1, share within 2 std in 92-98 %.
Every check is at ``ALPHA`` = 0.1 % (bands widened by 3.5 standard errors per method,
3 pooled), over 8 + 8 AGEBOT and 5 + 4 UR5-like sessions: an honest std fails the whole
test about 0.3 % of the time (seeded simulation of the whitened errors, t on the
sessions' dof), one 20 % optimistic a third of the time (AGEBOT) to 42 % (UR5). At 1 %
over 4 + 4 and 3 + 2 sessions an honest std failed 2.6-2.9 % of runs (a CI run's
sm-distance-tilt seed 9700 gave d2 38.6 on 14 where 16 reruns gave 4.8-30.8, mean
13.6) for the same power.
How a pool can show them: the errors of one session are strongly correlated (one
data set: an AGEBOT session's 14 parameters hold about 2-3 independent values), so
their raw RMS over a few sessions scatters far more than independent errors would.
Each session's errors are therefore whitened by its reported correlation
(``SessionScore.whitened``, ``d2 = z^T corr^-1 z``): for an honest std they are
independent unit errors whatever the correlation. Asserted, per method (band
widened by 3.5 of their exact standard errors) and pooled (by 3): the sum of d2
inside its two-sided 99.9 % interval (``d2_interval``: chi-square with the
estimated sigma's degrees of freedom), the whitened RMS and share within 2 in the
band. Per parameter, its raw RMS over the sessions (sessions are independent)
below what an honest std exceeds with probability ``ALPHA`` (Bonferroni; ``rms_bound``: each
error Student's t on its session's sigma dof;
the chi-square bound taken before, 2.5-2.8, failed an honest pool of the UR5-like
sessions several times in ten): how a bias shows that one session's bound cannot see (the
draw-wire zero's 4 std of issue 16). The raw RMS with the sessions' scatter as
its standard error, and the worst single error below its ``ALPHA`` bound (Student's t
at the fewest degrees of freedom), are asserted too, the raw coverage printed.

The seeds are consecutive and used nowhere else. A session may end in a named
refusal before it calibrates (no safe plan for the drawn arm, a reference
beyond an actuator limit, the live watch's EnvelopeExhausted: issue 10):
safe, counted, and the next seed runs, up to as many spare seeds as sessions;
a crash or a wrong result is never accepted.
"""
from __future__ import annotations

import math
from pathlib import Path

import pytest
from scipy.stats import norm
from scipy.stats import t as student_t

from calibration.solver.weighting import t_inflation

from station.planning.request import PlanRequest
from station.simulation.sessions import run_session, station_truth
from station.simulation.session_scores import d2_interval, rms_bound, summary

ROOT = Path(__file__).resolve().parents[2]
UR5 = str(ROOT / "fixtures" / "robots" / "ur5-like-hayati.toml")
BAND_RMS, BAND_COVERAGE = (0.9, 1.1), (0.92, 0.98)
ALPHA = 0.001
COVERAGE = 0.9545      # of 2 std, for a normal error

# (robot, method, fit poses, held out, first seed, sessions)
AGEBOT_PARTS = [("agebot-sm", "sm-distance-tilt", 24, 4, 9700, 8),
                ("agebot-sm", "sm-distance", 30, 4, 9720, 8)]
UR5_PARTS = [(UR5, "sm-distance-tilt", 40, 4, 8720, 5),
             (UR5, "sm-distance", 60, 4, 8740, 4)]


def _run_part(tmp_path, robot, method, count, validation, first, sessions):
    scores = []
    for seed in range(first, first + 2 * sessions):        # spare seeds for refusals
        if sum(sc.completed for sc in scores) == sessions:
            break
        sc = run_session(station_truth(robot, seed), tmp_path / f"{method}-{seed}", seed=seed,
                         method=method,
                         request=PlanRequest(count=count, validation=validation, seed=seed))
        assert sc.completed or sc.refused, (seed, sc.error)      # a refusal, never a crash
        scores.append(sc)
    done = [sc for sc in scores if sc.completed]
    assert len(done) == sessions, [(sc.seed, sc.error) for sc in scores]
    return done


def _figures(label, s) -> str:
    lo, hi = d2_interval(s["d2_k"], s["d2_dof"], ALPHA)
    return (f"{label}: {s['completed']} sessions, {s['n_errors']} errors; d2 sum "
            f"{s['d2_sum']:.1f} (honest {100 * (1 - ALPHA):g} %: {lo:.1f}-{hi:.1f}), whitened RMS "
            f"{s['rms_whitened']:.3f}, within 2 {100 * s['coverage_2std_whitened']:.1f} %; "
            f"raw err/std RMS {s['rms']:.3f} +- {s['rms_se']:.3f}, within 2 std "
            f"{100 * s['coverage_2std']:.1f} +- {100 * s['coverage_2std_se']:.1f} %, worst "
            f"{s['worst']:.2f}")


def _spread(s) -> tuple[float, float]:
    """Standard errors of the raw RMS and coverage: from the sessions' scatter, but
    never below those of as many independent normal errors."""
    n = s["n_errors"]
    return (max(s["rms_se"], 1 / math.sqrt(2 * n)),
            max(s["coverage_2std_se"], math.sqrt(COVERAGE * (1 - COVERAGE) / n)))


def _check_whitened(s, line, widen: float) -> None:
    """The whitened errors (independent for an honest std): d2's sum inside its
    ``1 - ALPHA`` interval, their RMS and share within 2 in the issue's band widened by
    ``widen`` of their standard errors (those of as many independent errors: exact here)."""
    lo, hi = d2_interval(s["d2_k"], s["d2_dof"], ALPHA)
    assert lo <= s["d2_sum"] <= hi, line
    n = s["n_errors"]
    rms_se, cov_se = 1 / math.sqrt(2 * n), math.sqrt(COVERAGE * (1 - COVERAGE) / n)
    assert BAND_RMS[0] - widen * rms_se <= s["rms_whitened"] <= BAND_RMS[1] + widen * rms_se, line
    assert BAND_COVERAGE[0] - widen * cov_se <= s["coverage_2std_whitened"] \
        <= BAND_COVERAGE[1] + widen * cov_se, line


def _check_pool(tmp_path, parts):
    everything, lines = [], []
    for part in parts:
        done = _run_part(tmp_path, *part)
        everything += done
        s = summary(done)
        lines.append(_figures(f"{Path(part[0]).stem} {part[1]}", s))
        print(lines[-1])
        print("  d2 per session: " + ", ".join(
            f"{sc.seed} {sc.d2:.1f}/{len(sc.z)} (dof {sc.dof:.0f})" for sc in done))
        _check_whitened(s, lines[-1], widen=3.5)
        # per parameter: its RMS over the sessions (independent across sessions) below
        # an honest std's ALPHA bound (Bonferroni over the parameters): a bias one
        # session's bound cannot see (the draw-wire zero's 4 std of issue 16)
        # (the errors are Student's t where sigma is estimated: rms_bound, not chi-square)
        per = s["rms_per_parameter"]
        print("  RMS per parameter: " + ", ".join(f"{n} {v[0]:.2f}" for n, v in per.items()))
        bounds: dict[tuple, float] = {}
        for name, (rms, k) in per.items():
            dofs = tuple(s["dof_per_parameter"][name])
            if dofs not in bounds:
                bounds[dofs] = rms_bound(dofs, ALPHA / len(per))
            assert rms < bounds[dofs], f"{lines[-1]}; {name}: RMS {rms:.2f} over {k} " \
                                       f"sessions (bound {bounds[dofs]:.2f})"
    s = summary(everything)
    lines.append(_figures("pooled", s))
    print(lines[-1])
    _check_whitened(s, lines, widen=3)
    # the raw errors' figures, with the sessions' scatter as their standard errors
    rms_se, cov_se = _spread(s)
    assert BAND_RMS[0] - 3 * rms_se <= s["rms"] <= BAND_RMS[1] + 3 * rms_se, lines
    dof = min(s["d2_dof"])
    worst_bound = (norm.isf(ALPHA / 2 / s["n_errors"]) if not math.isfinite(dof)
                   else student_t.isf(ALPHA / 2 / s["n_errors"], dof) / t_inflation(dof))
    assert s["worst"] < worst_bound, (lines, s["worst_per_parameter"])
    return s


@pytest.fixture
def no_report(monkeypatch):
    import station.outputs.report

    monkeypatch.setattr(station.outputs.report, "write_report",      # not what is judged here
                        lambda path, *a, **k: Path(path).write_text("report\n"))


@pytest.mark.slow
def test_agebot_sessions_report_an_honest_std(tmp_path, no_report):
    """AGEBOT arms drawn around the nominal; sm-distance-tilt and sm-distance. Its
    few parameters are strongly correlated, so one session's raw errors move together
    (the same four seeds once gave sm-distance-tilt RMS err/std 0.85, 1.02, 1.05 and
    1.49 in four runs): judged by the whitened errors and d2."""
    _check_pool(tmp_path, AGEBOT_PARTS)


@pytest.mark.slow
def test_robot_file_sessions_report_an_honest_std(tmp_path, no_report):
    """UR5-like arms (a robot file, judged against ``equivalent_truth``) drawn around
    the file's nominal; sm-distance-tilt and sm-distance."""
    _check_pool(tmp_path, UR5_PARTS)
