"""Whole simulated sessions on arms that are not the report's (issue 10).

Each arm is drawn around the nominal (``draw_truth``: gear ratios +-40 %, lengths
+-5 %, offsets +-0.03) with the noise real devices have; the simulator runs in its
own process and the session runs unattended (``station.simulation.sessions``). The
result is compared with the truth in the frame the session captured, angles
modulo 2 pi; ``distance_off`` with the simulated draw-wire's zero reading.
Seeds 9300-9309 and 9422 are used nowhere else (the bench uses 9100-).
"""
from __future__ import annotations

import numpy as np
import pytest

from calibration.robots import get_robot
from station.planning.request import PlanRequest
from station.simulation.sessions import run_session, station_truth
from station.simulation.session_scores import d2_interval, summary
from station.recording.trace import read_trace

FAR_SEED = 9422          # k1, k2, k4 32-38 % below the nominal, k3 16 % above
SLOW_SEEDS = range(9300, 9310)


def _heldout_refusal(score) -> bool:
    """Whether a session ended in the gate's named refusal of one held-out reading beyond
    its prediction's std (:func:`calibration.quality.worst_prediction`), and nothing else."""
    e = score.error.split(" (no parameter file written")[0]   # the failures, "; " between
    one = "; check that pose's reading"                         # the one failure's own "; "
    return (score.refused and e.startswith("FitQualityError: the fit failed the quality gate: "
                                           "validation: held-out pose")
            and "off the calibration's prediction" in e and e.count("; ") == e.count(one) == 1)


def _gear_deviation(truth) -> np.ndarray:
    robot = get_robot("agebot-sm")
    x = truth.xi()
    return np.array([x[robot.index(f"k{i}")] / robot.nominal[robot.index(f"k{i}")] - 1
                     for i in range(1, 5)])


@pytest.mark.heavy
def test_a_far_off_arm_completes_inside_the_envelope(tmp_path):
    """Three gear ratios a third off the nominal: planned with the nominal, poses would
    land up to 80 deg outside the box. The session scouts near the reference, refits,
    re-plans where the envelope stops it, stays within the tolerance of its box and
    ends with every parameter within 5 std of the truth."""
    truth = station_truth("agebot-sm", FAR_SEED)
    assert np.sum(np.abs(_gear_deviation(truth)) > 0.3) >= 3
    score = run_session(truth, tmp_path, seed=FAR_SEED,
                        request=PlanRequest(count=24, validation=6, seed=FAR_SEED))
    assert score.completed, score.error
    assert score.worst < 5.0, dict(zip(score.names, np.round(score.z, 2)))
    assert len(score.z) == 14 and "distance_off" in score.names
    # the tilt is watched (tolerance 5 deg); the position only through the distance
    # (5 cm), so a pose may lie a little farther than that from where it was planned
    assert score.excursion["phi"] <= 0.0873 and max(score.excursion[c] for c in "xyz") <= 0.1
    trace = read_trace(tmp_path / "run" / "trace.jsonl")
    # the scout and the middle round (6 each) on top of the 24 of the last round
    assert len(trace.fit_poses) == 36 and len(trace.validation_poses) == 6
    plans = [e for e in trace.events if e["kind"] == "plan"]
    assert plans[0]["box_scale"] < 1.0 and plans[-1]["box_scale"] <= 1.0   # scout first
    # where the envelope stopped the arm, the readings there taught the next plan
    stops = [e for e in trace.events if e["kind"] == "envelope"]
    assert all(set(e["readings"]) >= {"distance", "tilt"} for e in stops)
    if stops:
        assert any("envelope stop" in e["message"] for e in trace.events
                   if e["kind"] in ("info", "warning") and "refit" in e["message"])


@pytest.mark.heavy
def test_a_distance_session_beside_an_inclinometer_is_watched_in_tilt(tmp_path):
    """sm-distance on a drawn arm whose distances alone admit a mirrored model after the
    scout (bench seed 9160: its middle round went 0.27 m and 0.18 rad beyond the box,
    every distance as predicted). The station's inclinometer is recorded beside each
    pose, the rounds are planned with the fit of distance and tilt and the tilt is
    watched: every pose planned in the box stays within the tolerance of it, and the
    calibration (distance only) is within its std."""
    seed = 9160
    score = run_session(station_truth("agebot-sm", seed), tmp_path, seed=seed,
                        method="sm-distance",
                        request=PlanRequest(count=30, validation=4, seed=seed))
    assert score.completed, score.error
    assert score.worst < 5.0, dict(zip(score.names, np.round(score.z, 2)))
    assert max(score.excursion[c] for c in "xyz") <= 0.06 and score.excursion["phi"] <= 0.0873
    trace = read_trace(tmp_path / "run" / "trace.jsonl")
    assert all("tilt" in p for p in trace.poses) and "tilt" in trace.reference
    assert any("refitted" in e["message"] for e in trace.events if e["kind"] == "info")


@pytest.mark.slow
def test_ten_drawn_arms_are_calibrated_within_their_std(tmp_path):
    """Ten arms: every session completes (or one at most is refused by the held-out
    test's designed false alarm, :func:`_heldout_refusal`); every calibrated parameter lies within 5 std
    of the truth, and the errors are as large as the reported covariance says: the
    pooled ``d2 = e^T Sigma^-1 e`` of the 140 errors within its central 99.8 %
    (``d2_interval``), and the RMS of the errors whitened by each session's reported
    correlation between 0.8 and 1.3. A session's 14 errors move together (one data
    set), so the RMS of the raw error/std alone scatters from run to run beyond its
    nominal spread (0.74 and 1.19 in two runs of the same seeds under load, every
    session at its truth's minimum); it is printed. (The live watch
    compares each reading with where the actuators were when it was sampled and
    confirms a departure at rest, so a loaded machine does not stop a session; the
    final fit starts from two starts and keeps the better, so a drawn arm's fit does
    not end in a local minimum, whatever the noise draw.)"""
    scores = [run_session(station_truth("agebot-sm", s), tmp_path / f"s{s}", seed=s,
                          request=PlanRequest(count=24, validation=6, seed=s))
              for s in SLOW_SEEDS]
    failed = {sc.seed: sc.error for sc in scores if not sc.completed}
    # The gate refuses an honest session when a held-out reading lies beyond its
    # prediction's Bonferroni threshold: by design with probability OUTLIER_ALPHA (1e-3)
    # per session. One such named refusal in ten is that false-alarm rate (about 1 % of
    # runs), not a fault; two (about 5e-5 of runs) or any other failure is.
    assert len(failed) <= 1 and all(_heldout_refusal(sc) for sc in scores
                                    if not sc.completed), failed
    done = [sc for sc in scores if sc.completed]
    s = summary(done)
    assert s["worst"] < 5.0, s["worst_per_parameter"]
    assert s["n_errors"] == sum(s["d2_k"]) == len(done) * 14
    lo, hi = d2_interval(s["d2_k"], s["d2_dof"], alpha=0.002)
    print(f"ten arms: {len(done)} of 10 completed{'' if not failed else f' (refused: {failed})'}, worst |error|/std {s['worst']:.2f}, RMS "
          f"{s['rms']:.3f}, {100 * s['coverage_2std']:.1f} % within 2 std; whitened RMS "
          f"{s['rms_whitened']:.3f}, {100 * s['coverage_2std_whitened']:.1f} % within 2; d2 "
          f"{s['d2_sum']:.1f} (honest 99.8 %: {lo:.1f}-{hi:.1f})")
    assert lo <= s["d2_sum"] <= hi, s
    assert 0.8 <= s["rms_whitened"] <= 1.3, s
