"""Is the reported std of a whole session honest? Pooled over simulator seeds and arms.

One session's parameters are one draw: a bound on them (the fast tests in
``test_session.py`` and ``test_serial_session.py``: every parameter within 3
std) catches gross errors, not a std that is 20 % optimistic. Here whole
simulated sessions (``station.sim_sessions``: the simulator in its own process,
one unattended session, the result against the truth in the session's own
terms) are pooled over arms drawn around the nominal (``draw_truth``) with the
devices' noise (distance 1e-5 m, tilt 1.7e-4 rad per reading), one seed per
session for the arm, the simulator's noise and the plan.

Targets (issue 16): RMS of error/std in 0.9-1.1, share within 2 std in 92-98 %.
Sessions run against the wall clock, so a rerun of a seed is not bit-identical:
the figures are samples. The errors of one session are correlated, so the
sessions are the samples of their standard errors (``summary``: about 0.04 on
the RMS and 1.3 % on the coverage for a pool of ~250 errors, ~0.07 and 2.5 %
for one method's part). The pool as a whole must lie in the target band; each
method's part in the band widened by three of its standard errors. Per
parameter, its RMS over the pool's sessions must stay below what an honest std
exceeds with probability 1 % (Bonferroni over the parameters; about 2 std for 5
sessions): a bias that one session's 3 std cannot see. A bound of 3 std on
every one of ~250 errors would fail an honest std about half the time
(1 - 0.9973^250), so the pool's worst error is held to its own 1 % bound (about
4 std).

The seeds are consecutive and used nowhere else. A session may end in a named
refusal before it calibrates (a planner that finds no safe plan for the drawn
arm, an actuator limit): safe, counted, and at most one per method part; a
crash or a wrong result is never accepted.
"""
from __future__ import annotations

import math
from pathlib import Path

import pytest
from scipy.stats import chi2, norm

from station.planner import PlanRequest
from station.sim_sessions import run_session, station_truth, summary

ROOT = Path(__file__).resolve().parents[2]
UR5 = str(ROOT / "fixtures" / "robots" / "ur5-like-hayati.toml")
BAND_RMS, BAND_COVERAGE = (0.9, 1.1), (0.92, 0.98)
ALPHA = 0.01
COVERAGE = 0.9545      # of 2 std, for a normal error

# (robot, method, fit poses, held out, first seed, sessions)
AGEBOT_PARTS = [("agebot-sm", "sm-distance-tilt", 24, 4, 9700, 5),
                ("agebot-sm", "sm-distance", 30, 4, 9720, 5)]
UR5_PARTS = [(UR5, "sm-distance-tilt", 40, 4, 8720, 4),
             (UR5, "sm-distance", 60, 4, 8740, 2)]


def _run_part(tmp_path, robot, method, count, validation, first, sessions):
    scores = []
    for seed in range(first, first + sessions + 1):          # one spare seed for a refusal
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
    return (f"{label}: {s['completed']} sessions, {s['n_errors']} errors, RMS err/std "
            f"{s['rms']:.3f} +- {s['rms_se']:.3f}, within 2 std {100 * s['coverage_2std']:.1f} "
            f"+- {100 * s['coverage_2std_se']:.1f} %, worst {s['worst']:.2f}")


def _spread(s) -> tuple[float, float]:
    """Standard errors of the RMS and the coverage: from the sessions' scatter, but
    never below those of as many independent normal errors (a handful of sessions
    that all lie within 2 std would otherwise claim a coverage known exactly)."""
    n = s["n_errors"]
    return (max(s["rms_se"], 1 / math.sqrt(2 * n)),
            max(s["coverage_2std_se"], math.sqrt(COVERAGE * (1 - COVERAGE) / n)))


def _check_pool(tmp_path, parts):
    everything, lines = [], []
    for part in parts:
        done = _run_part(tmp_path, *part)
        everything += done
        s = summary(done)
        lines.append(_figures(f"{Path(part[0]).stem} {part[1]}", s))
        print(lines[-1])
        rms_se, cov_se = _spread(s)
        lo, hi = BAND_RMS
        assert lo - 3 * rms_se <= s["rms"] <= hi + 3 * rms_se, lines[-1]
        lo, hi = BAND_COVERAGE
        assert lo - 3 * cov_se <= s["coverage_2std"] <= hi + 3 * cov_se, lines[-1]
        # per parameter: its RMS over the sessions below an honest std's 1 % bound
        per = s["rms_per_parameter"]
        for name, (rms, k) in per.items():
            bound = math.sqrt(chi2.ppf(1 - ALPHA / len(per), k) / k)
            assert rms < bound, f"{lines[-1]}; {name}: RMS {rms:.2f} over {k} sessions " \
                                f"(bound {bound:.2f})"
    s = summary(everything)
    lines.append(_figures("pooled", s))
    print(lines[-1])
    rms_se, cov_se = _spread(s)
    assert BAND_RMS[0] - 2 * rms_se <= s["rms"] <= BAND_RMS[1] + 2 * rms_se, lines
    assert BAND_COVERAGE[0] - 2 * cov_se <= s["coverage_2std"] \
        <= BAND_COVERAGE[1] + 2 * cov_se, lines
    worst_bound = norm.isf(ALPHA / 2 / s["n_errors"])
    assert s["worst"] < worst_bound, (lines, s["worst_per_parameter"])
    return s


@pytest.fixture
def no_report(monkeypatch):
    import station.report

    monkeypatch.setattr(station.report, "write_report",      # not what is judged here
                        lambda path, *a, **k: Path(path).write_text("report\n"))


@pytest.mark.slow
def test_agebot_sessions_report_an_honest_std(tmp_path, no_report):
    """AGEBOT arms drawn around the nominal; sm-distance-tilt and sm-distance."""
    _check_pool(tmp_path, AGEBOT_PARTS)


@pytest.mark.slow
def test_robot_file_sessions_report_an_honest_std(tmp_path, no_report):
    """UR5-like arms (a robot file, judged against ``equivalent_truth``) drawn around
    the file's nominal; sm-distance-tilt and sm-distance."""
    _check_pool(tmp_path, UR5_PARTS)
