"""The wrist's growing box (station/planning/wrist_plan.py) without devices: the planner's
rounds against a drawn wrist's true kinematics, the envelope checks and the stops."""
from __future__ import annotations

import math

import numpy as np
import pytest

from calibration.errors import CalibrationError
from calibration.robots import get_robot
from calibration.robots.agebot_pm import envelope_violation, gravity_tilt, rot_xyz
from drivers.sim.truth import draw_truth
from station.planning.request import PlanRequest
from station.planning.wrist_plan import (ADVICE, BOX_DEG, TOLERANCE_DEG, WristPlanner,
                                WristStopped)

ROBOT = get_robot("agebot-pm")
STROKE = [[-1000.0, 6000.0]] * 3
# (7104 planned in the model's absolute heading reached 21.6 deg, 37 before rejected
# steps were retried by the parabola along them: no longer a case that shows it)
SEEDS_TILT = [7109, 7110]


def _truth(seed):
    return draw_truth("agebot-pm", np.random.default_rng(seed)).xi()


def _inclinometer(X, rng):
    """pm-tilt's reading (roll, pitch) of the orientation ``X``, noisy."""
    return np.array(gravity_tilt(rot_xyz(X)[0])) + rng.normal(0, 1.7e-4, 2)


def _session(xi, planner, *, sensor=lambda X, rng: X + rng.normal(0, 1.7e-4, 3), seed=0):
    """Execute the planner's rounds the way Session.execute does, measuring with the
    true kinematics ``xi``; returns (records, true orientations, watch messages)."""
    rng = np.random.default_rng(seed)
    home_qm = ROBOT.ik(np.zeros(3), xi)
    tilt = planner.method == "pm-tilt"
    if tilt:
        sensor = _inclinometer
    home = np.r_[sensor(np.zeros(3), rng), 0.0] if tilt else sensor(np.zeros(3), rng)
    poses, _ = planner.scout(home_qm, home)
    records, true_X, trips, faults = [], [], [], []
    last = np.zeros(3)
    nxt = len(poses)
    while True:
        dropped = set()
        for p in poses:
            if p.index in dropped:
                continue
            try:
                last = ROBOT.fk(np.atleast_2d(p.qm), xi, guess=last)[0]
            except CalibrationError:      # the simulator's limit fault: the pose is skipped
                faults.append(p.index)
                continue
            rec = {"index": len(records), "qm": list(p.qm), "use": p.use,
                   "tilt" if tilt else "orientation": list(sensor(last, rng))}
            msg = planner.watch(p, rec)
            if msg is not None:
                planner.tripped()
                trips.append(msg)
                dropped |= {q.index for q in poses if q.round == p.round}
                continue
            records.append(rec)
            true_X.append(last)
        fits = sum(r["use"] == "fit" for r in records)
        out = planner.next_round(records, nxt, records[-1]["qm"], fits, len(records) - fits)
        if out is None:
            return records, np.array(true_X), trips + faults
        poses, info = out
        nxt += len(poses)


@pytest.mark.parametrize("seed", [7101, 7102, 7103])
def test_far_off_wrists_grow_to_the_box_without_leaving_it(seed):
    xi = _truth(seed)
    planner = WristPlanner("pm-fk", PlanRequest(count=24, validation=5, seed=seed),
                           qm_range=STROKE)
    records, X, trips = _session(xi, planner)
    assert not trips
    assert np.degrees(np.abs(X).max()) < BOX_DEG + TOLERANCE_DEG
    assert np.degrees(np.abs(X).max()) > 0.8 * BOX_DEG           # and the box was reached
    assert sum(r["use"] == "fit" for r in records) == 24
    assert sum(r["use"] == "validation" for r in records) == 5


@pytest.mark.parametrize("seed", SEEDS_TILT)
def test_pm_tilt_box_is_centred_on_the_heading_of_home(seed, monkeypatch):
    """The inclinometer does not see the heading, and a model fitted near home gets it
    wrong by degrees: pm-tilt's box is centred on the model's heading at home, so the
    true wrist stays in the box (planned in the model's absolute heading it does not)."""
    def run():
        planner = WristPlanner("pm-tilt", PlanRequest(count=24, validation=5, seed=seed),
                               qm_range=STROKE)
        return _session(xi, planner)[1]
    xi = _truth(seed)
    X = run()
    # (the bound; on twelve wrists 7104-7115 the largest was 23.7 deg, up to
    # 0.7 deg past the tolerance: two readings a pose extrapolate less well)
    assert 0.8 * BOX_DEG < np.degrees(np.abs(X).max()) < 25.0
    monkeypatch.setattr(WristPlanner, "home_heading", lambda self: 0.0)
    assert np.degrees(np.abs(run()).max()) > 30.0     # 55 and 33 deg


def test_the_scout_is_planned_relative_to_home():
    """The nominal's absolute IK puts a drawn wrist's rods centimetres off; relative to
    home, the scout poses stay within a few times the scout box."""
    xi = _truth(7104)
    planner = WristPlanner("pm-fk", PlanRequest(seed=1), qm_range=STROKE)
    home = ROBOT.ik(np.zeros(3), xi)
    poses, info = planner.scout(home, np.zeros(3))
    X = ROBOT.fk(np.array([p.qm for p in poses]), xi)
    assert info["round"] == 0 and not info["final"]
    assert np.degrees(np.abs(X).max()) < 15.0


def test_planned_poses_respect_the_stroke():
    xi = _truth(7105)
    home = ROBOT.ik(np.zeros(3), xi)
    tight = [[h - 150.0, h + 150.0] for h in home]
    planner = WristPlanner("pm-fk", PlanRequest(seed=2), qm_range=tight)
    poses, _ = planner.scout(home, np.zeros(3))
    qm = np.array([p.qm for p in poses])
    assert np.all(qm >= np.array(tight)[:, 0]) and np.all(qm <= np.array(tight)[:, 1])
    assert "stroke" in envelope_violation(np.zeros(3), xi, home + [200.0, 0, 0], tight)


def test_a_wrist_the_model_cannot_follow_stops_with_advice():
    """A sensor that does not follow the platform (axes mapped wrong: it reads twice the
    angles): the model's predictions miss, each round is dropped and re-planned with
    a smaller step, and after MAX_TRIPS the session stops and says what to do."""
    xi = _truth(7106)
    planner = WristPlanner("pm-fk", PlanRequest(count=24, validation=5, seed=4),
                           qm_range=STROKE)
    twisted = lambda X, rng: np.array([X[0] + 2.5 * X[1], X[1], X[2] - 2 * X[0]])  # noqa: E731
    with pytest.raises(WristStopped) as e:
        _session(xi, planner, sensor=twisted)
    msg = str(e.value)
    assert "gear ratios" in msg and ADVICE in msg
    assert planner.rounds == 1        # stopped after the scout, before any wider round


def test_watch_names_the_deviation():
    xi = _truth(7107)
    planner = WristPlanner("pm-fk", PlanRequest(seed=5))
    planner.xi = xi
    X = np.radians([5.0, -3.0, 2.0])
    qm = ROBOT.ik(X, xi)
    from station.recording.planned_pose import PlannedPose
    pose = PlannedPose(3, tuple(qm), tuple(X), "fit", 1)
    assert planner.watch(pose, {"qm": list(qm), "orientation": list(X)}) is None
    off = X + [0.0, math.radians(TOLERANCE_DEG + 1), 0.0]
    msg = planner.watch(pose, {"qm": list(qm), "orientation": list(off)})
    assert msg and "beta" in msg and "pose 3" in msg
