"""The safety envelope: actuator limits from the config, the live watch against the
model while moving, and the simulated arm's physical limits seen over the wire."""
from __future__ import annotations

import contextlib
import dataclasses
import math
import tomllib
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from calibration.errors import ConfigError
from calibration.robots import get_robot
from drivers.config import ENVELOPE_TOLERANCE, load_station_config, parse_station_config
from drivers.errors import ProtocolError
from drivers.rig import Rig
from drivers.sim.server import SimulatorProcess
from drivers.sim.truth import load_truth
from station.planning.envelope import (EnvelopeStop, Track, box_points, departures, limit_violation,
                              live_departures, sm_predictor, watched_move)
from station.simulation.sessions import fast_config

ROOT = Path(__file__).resolve().parents[2]
SIM_SM = ROOT / "fixtures" / "stations" / "sim-sm.toml"
UNSEEN = ROOT / "fixtures" / "truth" / "agebot-sm-unseen.json"


def test_config_limits_and_tolerances():
    env = load_station_config(SIM_SM).envelope
    assert env.qm_min == (-85.0, -250.0, -250.0, -250.0) and env.qm_max[0] == 85.0
    assert env.tolerance["distance"] == 0.05 and env.latency == 0.15
    assert limit_violation([0, 0, 0, 0], env) is None
    why = limit_violation([0, 0, 250.0, 0], env)
    assert "actuator 3" in why and "qm_max 235" in why
    data = tomllib.loads(SIM_SM.read_text())
    assert parse_station_config({**data, "envelope": {}}).envelope.tolerance == ENVELOPE_TOLERANCE
    bad = {**data, "envelope": {"qm_min": [0, 0, 0, 0], "qm_max": [1, 1, -1, 1]}}
    with pytest.raises(ConfigError, match="envelope.qm_max: every"):
        parse_station_config(bad, "st.toml")
    with pytest.raises(ConfigError, match="envelope.tolerance.speed: unknown channel"):
        parse_station_config({**data, "envelope": {"tolerance": {"speed": 1.0}}}, "st.toml")


def test_departures_along_the_path_and_modulo_2pi():
    tol = {"distance": 0.01, "tilt": 0.05}
    path = [{"distance": 0.10, "tilt": 3.12}, {"distance": 0.20, "tilt": -3.10}]
    # somewhere on the path it matches; the tilt near +-pi compares modulo 2 pi
    assert departures({"distance": 0.205, "tilt": 3.14}, path, tol) == {}
    bad = departures({"distance": 0.30, "tilt": 0.0}, path, tol)
    assert set(bad) == {"distance", "tilt"} and bad["distance"] == (0.30, 0.20)
    assert departures({"distance": 0.3}, {"distance": 0.3, "yaw": 1.0}, tol) == {}


@pytest.fixture(scope="module")
def sim_rig(tmp_path_factory):
    """The unseen arm in its own process, its devices opened (4x faster moves)."""
    folder = tmp_path_factory.mktemp("envelope")
    cfg = fast_config("agebot-sm", folder)
    with SimulatorProcess("agebot-sm", truth=str(UNSEEN), config=str(cfg), seed=21) as sim:
        with Rig(sim.station_config()) as rig:
            yield sim, rig


def test_the_simulated_arm_refuses_a_target_beyond_its_travel(sim_rig):
    """A set-point outside the physical range (the rail's +-2 m through the true
    transmission) is a drive FAULT with EMCY 0x8612 naming the node and, in its
    manufacturer bytes, the travel; the axis stays;
    after a reset the arm moves again."""
    sim, rig = sim_rig
    truth = load_truth(UNSEEN)
    names = get_robot("agebot-sm").param_names
    k1, off1 = truth.xi()[names.index("k1")], truth.xi()[names.index("q1_off")]
    start = np.array(rig.qm())
    beyond = start.copy()
    beyond[0] = (2.0 - off1) / k1 + 1.0           # 1 unit past the rail's end
    with pytest.raises(ProtocolError) as e:
        rig.move_to(beyond)
    assert e.value.code == 0x8612 and "reference limit (drive says 'TRVL')" in str(e.value)
    assert "node 1" in str(e.value)
    with sim.control() as ctl:
        np.testing.assert_allclose(ctl.call(state=True)["qm"], start, atol=1e-4)   # one increment
    rig.recover()
    inside = start.copy()
    inside[0] += 2.0
    rig.move_to(inside)
    np.testing.assert_allclose(rig.qm(), inside, atol=1e-4)
    rig.move_to(start)


@contextlib.contextmanager
def slowed(rig, factor: float):
    """The drives' profile velocity (0x6081) ``factor`` times lower while in the block
    (the actuators' ``velocity`` too, which the watch predicts the arrival from)."""
    act = rig.actuators
    before = list(act.velocity)

    def write(velocity):
        for i, nid in enumerate(act.nodes):
            act.sdo_write(nid, 0x6081, round(velocity[i] * act.resolution[i]))
        act.velocity = list(velocity)

    write([v / factor for v in before])
    try:
        yield
    finally:
        write(before)


def test_the_watch_stops_a_move_the_model_does_not_explain(sim_rig):
    """The true model sees the move through; a model whose k2 is 30 % off stops the arm
    on the way, and says which channel departed (confirmed at rest)."""
    sim, rig = sim_rig
    robot = get_robot("agebot-sm")
    truth = load_truth(UNSEEN).xi()
    env = dataclasses.replace(rig.config.envelope, tolerance={"distance": 0.02, "tilt": 0.03})
    start = np.array(rig.qm())
    rig.zero_drawwire()
    target = start + np.array([4.0, 30.0, -25.0, 20.0])
    watched_move(rig, target, sm_predictor("sm-distance-tilt", robot, truth, start), env, 20.0)
    np.testing.assert_allclose(rig.qm(), target, atol=1e-4)
    watched_move(rig, start, sm_predictor("sm-distance-tilt", robot, truth, start), env, 20.0)
    wrong = truth.copy()
    wrong[robot.index("k2")] *= 1.3
    # departs more the farther it goes: four times as far at a quarter of the speed
    # (0.7 s rather than 0.06 s of motion, so that the watch reads the arm on the way
    # however busy the machine: on a loaded one the arm was there before a second reading)
    far = start + 4 * (target - start)
    with pytest.raises(EnvelopeStop) as e, slowed(rig, 4.0):
        watched_move(rig, far, sm_predictor("sm-distance-tilt", robot, wrong, start), env,
                     20.0)
    assert "tilt" in e.value.departed or "distance" in e.value.departed
    here = np.array(rig.qm())
    assert np.max(np.abs(here - far)) > 1.0          # stopped short of the target
    np.testing.assert_allclose(here, e.value.qm, atol=5.0)     # where it was seen, give or take a read
    # what the arm really reads where it stopped (the next plan learns from it): the
    # true model's prediction at the stop's qm, within the readings' noise
    true_there = sm_predictor("sm-distance-tilt", robot, truth, start)(e.value.qm)
    assert set(e.value.readings) >= {"distance", "tilt"}
    assert abs(e.value.readings["distance"] - true_there["distance"]) < 1e-3
    assert abs(e.value.readings["tilt"] - true_there["tilt"]) < 3e-3
    with sim.control() as ctl:
        assert ctl.call(state=True)["target_reached"]
    assert math.isfinite(here.sum())


def test_the_watch_wakes_when_the_move_ends_not_a_poll_later(sim_rig, monkeypatch):
    """The watch reads the sensors every ``[envelope] poll`` s, but no later than when
    the drives' profile (velocity and acceleration of the station config) ends the
    move: it then follows the last millimetres closely and returns, instead of sleeping
    through most of a poll with the arm already there. With a poll of 30 s every nap
    ends by the predicted arrival."""
    from station.planning import envelope

    sim, rig = sim_rig
    robot = get_robot("agebot-sm")
    truth = load_truth(UNSEEN).xi()
    env = dataclasses.replace(rig.config.envelope, poll=30.0)
    start = np.array(rig.qm())
    rig.zero_drawwire()
    target = start + np.array([4.0, 30.0, -25.0, 20.0])
    act = rig.actuators
    duration = envelope.move_duration(start, target, act.velocity, act.acceleration)
    assert 0.05 < duration < 5.0
    naps, nap = [], envelope.nap

    def recorded(poll, arrival):
        naps.append(nap(poll, arrival))
        return min(naps[-1], 0.01)      # a 30 s nap would not be waited for

    monkeypatch.setattr(envelope, "nap", recorded)
    try:
        watched_move(rig, target, sm_predictor("sm-distance-tilt", robot, truth, start), env,
                     20.0)
        np.testing.assert_allclose(rig.qm(), target, atol=1e-4)
    finally:
        rig.move_to(start)
    assert max(naps, default=0.0) <= duration


def test_move_duration_is_the_simulated_axes_profile():
    from drivers.sim.axis import SimAxis
    from station.planning.envelope import move_duration

    for d, v, a in ((0.3, 50.0, 400.0), (40.0, 50.0, 400.0), (6.25, 50.0, 400.0),
                    (-30.0, 200.0, 2000.0), (0.0, 10.0, 10.0)):
        axis = SimAxis(1.0, v, a)
        axis.command(1.0 + d)
        want = axis._duration()
        assert move_duration([1.0], [1.0 + d], v, a) == pytest.approx(want, rel=1e-12, abs=0)
    assert move_duration([0.0, 0.0], [1.0, 40.0], [50.0, 50.0], [400.0, 400.0]) == \
        pytest.approx(40 / 50 + 50 / 400)


def test_a_simulated_axis_remembers_where_it_was_before_a_new_set_point():
    """A lagging sensor shows where the axis was some time ago, also across a stop or a
    new set-point: the positions before a command are the move it superseded, not the
    point it was commanded from (a stop made the late inclinometer show the stop point
    at once, so a reading at rest 'confirmed' a departure that was only the lag)."""
    from drivers.sim.axis import SimAxis

    now = [0.0]
    axis = SimAxis(0.0, 10.0, 100.0, clock=lambda: now[0])
    axis.command(100.0)
    now[0] = 1.0
    moving = axis.position()
    axis.stop()                                  # at 1.0 s, 10 units/s
    now[0] = 1.2
    assert axis.position() == pytest.approx(moving)
    assert axis.position_at(0.9) == pytest.approx(moving - 1.0)   # still moving then
    assert axis.position_at(0.05) == pytest.approx(0.5 * 100.0 * 0.05 ** 2)
    assert axis.position_at(-1.0) == 0.0
    axis.command(0.0)                            # back, from 1.2 s
    now[0] = 1.5
    assert axis.position_at(1.1) == pytest.approx(moving)     # stopped then
    assert axis.position_at(0.9) == pytest.approx(moving - 1.0)
    assert axis.position_at(1.3) < moving


def test_a_late_sensor_does_not_stop_a_move_the_model_explains(sim_rig):
    """The inclinometer's frames show the arm as it was 0.4 s before (a filter's delay),
    more than the config's latency (0.15 s). A long fast move with the true model
    departs on the way; the readings at rest agree, and the move goes on to its target
    (the watch it replaced stopped it). The same move with a wrong model is stopped,
    with its departure confirmed at rest."""
    sim, rig = sim_rig
    robot = get_robot("agebot-sm")
    truth = load_truth(UNSEEN).xi()
    env = rig.config.envelope
    start = np.array(rig.qm())
    rig.zero_drawwire()
    target = start + np.array([20.0, 120.0, -100.0, 80.0])
    predict = sm_predictor("sm-distance-tilt", robot, truth, start)
    with sim.control() as ctl:
        ctl.call(faults={"inclinometer_lag_s": 0.4})
    try:
        for a, b in ((start, target), (target, start)):
            watched_move(rig, b, predict, env, 20.0)
            np.testing.assert_allclose(rig.qm(), b, atol=1e-4)
        wrong = truth.copy()
        wrong[robot.index("k2")] *= 1.3
        with pytest.raises(EnvelopeStop) as e:
            watched_move(rig, target, sm_predictor("sm-distance-tilt", robot, wrong, start),
                         env, 20.0)
        assert "tilt" in e.value.departed or "distance" in e.value.departed
    finally:
        with sim.control() as ctl:
            ctl.call(faults={"inclinometer_lag_s": 0.0})
        rig.move_to(start)


def test_each_reading_is_compared_where_the_actuators_were_when_it_was_sampled():
    """Axes move one way each, at their own pace, so between two actuator readings the
    arm is anywhere in their box, not on the straight line between them. A reading
    sampled between them is explained by a pose there; one sampled before the move is
    compared with where the move started."""
    track = Track(2)
    track.add({"qm1": (0.0, 0.0, 0.01), "qm2": (0.0, 0.0, 0.01)})
    track.add({"qm1": (1.0, 0.10, 0.11), "qm2": (0.0, 0.10, 0.11)})
    track.add({"qm1": (1.0, 0.20, 0.21), "qm2": (1.0, 0.20, 0.21)})
    np.testing.assert_allclose(track.box(0.05, 0.09), [[0.0, 1.0], [0.0, 0.0]])
    np.testing.assert_allclose(track.box(0.12, 0.15), [[1.0, 1.0], [0.0, 1.0]])
    np.testing.assert_allclose(track.box(0.05, 0.15), [[0.0, 1.0], [0.0, 1.0]])
    np.testing.assert_allclose(track.box(-0.5, -0.1), [[0.0, 0.0], [0.0, 0.0]])
    assert len(box_points(track.box(0.05, 0.09))) == 3      # 2 corners + centre

    def predict(q):        # "tilt" qm1 - qm2: 0 on the diagonal, 1 at the corner (1, 0)
        q = np.atleast_2d(q)
        return {"tilt": q[:, 0] - q[:, 1]}
    tol = {"tilt": 0.1}
    # qm1 moved first: tilt 1 halfway, off the diagonal the straight line predicts
    assert live_departures({"tilt": (1.0, 0.05, 0.15)}, track, predict, tol) == {}
    bad = live_departures({"tilt": (1.0, -0.5, -0.1)}, track, predict, tol)
    assert bad == {"tilt": (1.0, 0.0)}
    # a reading the method does not predict (sm-distance at a station with a tilt
    # sensor) is not watched; it never stops the move (was a KeyError)
    tol2 = {"tilt": 0.1, "distance": 0.05}
    assert live_departures({"tilt": (1.0, 0.05, 0.15), "distance": (9.0, 0.05, 0.15)},
                           track, lambda q: {"distance": np.full(len(q), 9.0)}, tol2) == {}


def test_a_suggested_reference_beyond_a_limit_is_brought_inside():
    """The reference the nominal model suggests may lie beyond a drawn arm's limit
    (sm-distance's actuator 4 at -212.9 against -205): it is brought 5 % of the range
    inside, the other actuators kept; inside the limits, or without any, it is the
    nominal's own."""
    from station.planning.arm_plan import reference_pose

    robot = get_robot("agebot-sm")
    free, _, _ = reference_pose("sm-distance", robot.nominal)
    lo = np.array([-50.0, -200.0, -100.0, free[3] + 7.9])
    hi = np.array([50.0, 200.0, 300.0, 0.0])
    qm, _, _ = reference_pose("sm-distance", robot.nominal, np.column_stack([lo, hi]))
    assert limit_violation(qm, SimpleNamespace(qm_min=lo, qm_max=hi)) is None
    np.testing.assert_allclose(qm[:3], free[:3])
    assert qm[3] == pytest.approx(lo[3] + 0.05 * (hi[3] - lo[3]))
    wide = np.column_stack([np.full(4, -1e3), np.full(4, 1e3)])
    np.testing.assert_allclose(reference_pose("sm-distance", robot.nominal, wide)[0], free)
    for method in ("sm-distance", "sm-distance-tilt"):
        np.testing.assert_allclose(reference_pose(method, robot.nominal, None)[0],
                                   reference_pose(method, robot.nominal)[0])
