"""The simulated wrist's physical limits: a command it cannot follow stops it at the
last point inside its envelope and faults the drive with a name of what was hit,
seen by the station over CANopen (EMCY 0x8612 with manufacturer bytes)."""
from __future__ import annotations

import numpy as np
import pytest

from calibration.robots.agebot_pm import PASSIVE_RANGE, envelope_hit, passive_angles
from drivers.config import load_station_config, parse_station_config
from drivers.endpoints import with_endpoints
from drivers.errors import ProtocolError
from drivers.rig import Rig
from drivers.sim.robot import LIMIT_NAMES, SimulatedAgebot
from drivers.sim.server import SimulatorProcess
from drivers.sim.truth import report_truth
from calibration.errors import ConfigError
from tests.station.test_session import FIX, fast_config


class Clock:
    t = 0.0

    def __call__(self):
        return self.t


def _robot(qm_range=None):
    clock = Clock()
    return SimulatedAgebot(report_truth("agebot-pm"), clock=clock, qm_range=qm_range), clock


@pytest.mark.parametrize("target, kinds", [
    ((2150.0, 1425.0, 1783.0), {"stroke"}),
    ((2018.0, 1425.0, -500.0), {"centre joint", "reach", "slider joint", "platform joint"}),
    ((2018.0, 4000.0, 4000.0), {"centre joint", "reach", "slider joint", "platform joint"}),
])
def test_the_simulated_wrist_stops_inside_its_envelope(target, kinds):
    robot, clock = _robot([[1900, 2100], [-1000, 6000], [-1000, 6000]])
    robot.move_to(target)
    clock.t += 10.0
    axis, kind = robot.supervise()
    assert kind in kinds and 0 <= axis < 3
    qm = robot.qm()
    assert np.max(np.abs(qm - target)) > 1.0            # stopped short of the target
    assert envelope_hit(robot.ee_pose(), robot.xi, qm, robot.qm_range) is None   # stopped inside
    clock.t += 10.0
    assert robot.supervise() is None and np.allclose(robot.qm(), qm)   # and stays there
    robot.move_to(robot.home_qm)                                        # back out is allowed
    clock.t += 10.0
    assert robot.supervise() is None and np.allclose(robot.qm(), robot.home_qm)


def test_a_move_inside_the_envelope_is_not_stopped():
    robot, clock = _robot([[0, 6000]] * 3)
    robot.move_to((2100.0, 1500.0, 1800.0))
    clock.t += 10.0
    assert robot.supervise() is None and np.allclose(robot.qm(), (2100.0, 1500.0, 1800.0))
    a = passive_angles(robot.ee_pose(), robot.xi)
    assert all(np.all(a[k] <= PASSIVE_RANGE[k]) for k in PASSIVE_RANGE)



def test_a_walk_taken_at_once_finds_what_the_walk_point_by_point_finds(monkeypatch):
    """The walk since the last check is solved at once where it stays inside the
    envelope (drivers.sim.robot.SimulatedAgebot._walk_at_once), else point by point:
    over random moves, some out past a limit, the same stops and the same poses as
    point by point alone."""
    rng = np.random.default_rng(7)
    envelope = [[1500, 2600], [900, 2000], [1200, 2400]]
    both, alone = _robot(envelope), _robot(envelope)
    monkeypatch.setattr(alone[0], "_walk_at_once", lambda Q, X: None)
    at_once, walk = [], both[0]._walk_at_once

    def counted(Q, X):
        poses = walk(Q, X)
        if poses is not None:
            at_once.append(len(poses))
        return poses
    monkeypatch.setattr(both[0], "_walk_at_once", counted)
    hits = 0
    for _ in range(40):
        target = both[0].qm() + rng.uniform(-500.0, 500.0, 3)
        for robot, _ in (both, alone):
            robot.move_to(target)
        for dt in (rng.uniform(0.02, 0.3), 10.0):   # during the move, then after it
            seen = []
            for robot, clock in (both, alone):
                clock.t += dt
                seen.append((robot.supervise(), robot.qm(), robot._checked[2]))
            assert seen[0][0] == seen[1][0]
            assert np.allclose(seen[0][1], seen[1][1], atol=1e-9)
            assert np.allclose(seen[0][2], seen[1][2], atol=1e-9)
            hits += seen[0][0] is not None
    print("hits", hits, "walks at once", len(at_once), "points", sum(at_once))
    assert 5 <= hits and len(at_once) >= 20     # both kinds of walk were taken



def test_beyond_envelope_says_what_envelope_hit_says_pose_by_pose():
    """The at-once check (calibration.robots.agebot_pm.beyond_envelope) and the one
    that names what is hit agree on every pose, inside and beyond."""
    from calibration.robots.agebot_pm import AgebotPM, beyond_envelope

    robot, _ = _robot()
    xi, rng = robot.xi, np.random.default_rng(3)
    X = rng.uniform(-0.6, 0.6, (400, 3))
    qm = AgebotPM().ik_actuators(X, xi, strict=False)
    qm_range = [[1500, 2600], [900, 2000], [1200, 2400]]
    got = beyond_envelope(X, xi, qm, qm_range)
    want = [envelope_hit(x, xi, q, qm_range) is not None for x, q in zip(X, qm)]
    assert got.tolist() == want and 20 < sum(want) < 380

def test_a_too_far_command_faults_with_the_limit_named_over_the_wire(tmp_path):
    cfg = fast_config(tmp_path, "agebot-pm")
    text = cfg.read_text().replace("qm_max = [6000.0, 6000.0, 6000.0]",
                                   "qm_max = [2100.0, 6000.0, 6000.0]")
    assert text != cfg.read_text()
    cfg.write_text(text)
    with SimulatorProcess("agebot-pm", config=str(cfg), seed=2) as sim:
        config = with_endpoints(load_station_config(cfg), sim.endpoints, source="simulator")
        rig = Rig(config).open()
        try:
            home = np.array(rig.qm())
            with pytest.raises(ProtocolError) as err:       # slider 1 beyond its stroke
                rig.move_to(home + [300.0, 0.0, 0.0])
            assert err.value.code == 0x8612 and "STRK" in str(err.value)
            assert "node 1" in str(err.value) or err.value.device.endswith("1")
            rig.recover()
            with pytest.raises(ProtocolError) as err:       # slider 3 alone, far: a joint or a rod
                rig.move_to(home + [0.0, 0.0, -2500.0])
            names = [n.decode() for k, n in LIMIT_NAMES.items() if k != "stroke"]
            assert err.value.code == 0x8612 and any(n in str(err.value) for n in names), err.value
            rig.recover()
            rig.move_to(home)                               # back home: no fault
            assert np.allclose(rig.qm(), home, atol=1.0)
        finally:
            rig.close()


def test_limits_in_the_station_config():
    base = {"robot": "agebot-pm", "canopen": {"interface": "virtual", "nodes": [1, 2, 3],
                                              "increments_per_unit": [1000, 1000, 1000]}}
    assert parse_station_config(base).envelope.qm_range is None
    c = parse_station_config({**base, "envelope": {"qm_min": [0.0] * 3, "qm_max": [1.0, 2.0, 3.0]}})
    np.testing.assert_array_equal(c.envelope.qm_range, [[0.0, 1.0], [0.0, 2.0], [0.0, 3.0]])
    c = parse_station_config({**base, "envelope": {"qm_max": [1.0, 2.0, 3.0]}})
    assert c.envelope.qm_range[0, 0] == -np.inf
    with pytest.raises(ConfigError, match="envelope.qm_max"):
        parse_station_config({**base, "envelope": {"qm_min": [5.0] * 3, "qm_max": [1.0, 2.0, 3.0]}})
    assert load_station_config(FIX / "stations" / "sim-pm.toml").envelope.qm_range is not None


def test_a_move_out_past_the_stroke_and_back_between_two_checks_is_caught():
    """The walk samples the path, not the net displacement: out past the rail's stroke
    and commanded back before the next check is a hit (the net move is nil)."""
    robot, clock = _robot([[1900, 2100], [-1000, 6000], [-1000, 6000]])
    home = robot.qm()
    assert robot.supervise() is None
    robot.move_to((2150.0, home[1], home[2]))
    clock.t += 10.0                                      # there, beyond the stroke's 2100
    robot.move_to(home)                                  # and back, unchecked
    clock.t += 10.0
    assert np.allclose(robot.qm(), home)
    axis, kind = robot.supervise()
    assert kind == "stroke" and axis == 0


def test_the_axis_travel_counts_every_move():
    from drivers.sim.axis import SimAxis

    t = [0.0]
    ax = SimAxis(0.0, 1.0, 10.0, clock=lambda: t[0])
    ax.command(2.0)
    t[0] = 1.0                                            # 0.95 of the way
    mid = ax.position()
    ax.command(0.0)
    t[0] = 10.0
    assert ax.position() == 0.0
    assert ax.travel(0.0, 10.0) == pytest.approx(2 * mid)
    assert ax.travel(0.0, 1.0) == pytest.approx(mid) and ax.travel(5.0, 10.0) == 0.0
