"""Any serial arm at the station: the simulated station of a robot file, its
planning and a whole sm-distance-tilt session, judged by held-out point-to-point
distances (pairs of random poses in the limits) against the simulator's truth."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from calibration.errors import ConfigError
from drivers.config import parse_station_config
from drivers.robot_file import load_robot_file
from drivers.sim.serial_robot import (SimulatedSerial, draw_serial_truth, sim_config,
                                      sim_config_data)
from drivers.sim.server import SimulatorProcess
from drivers.sim.truth import save_truth
from station.planning import serial_plan
from station.outputs.export import calibrated_model
from station.outputs.params_file import read_params
from station.planning.request import PlanRequest
from station.session.session import Session
from station.simulation.serial_sessions import equivalent_truth, serial_config, serial_truth_vector
from station.recording.trace import read_trace
from tests.simconfig import quick_text
from tests.station.test_session import session_bound

ROOT = Path(__file__).resolve().parents[2]
HAYATI = ROOT / "fixtures" / "robots" / "ur5-like-hayati.toml"
DH = ROOT / "fixtures" / "robots" / "ur5-like-dh.toml"
NOISE = {"distance": 1e-5, "tilt": 1e-4, "qm": 1e-6}


class FakeClock:
    def __init__(self):
        self.t = 0.0

    def __call__(self):
        return self.t


def _truth_file(tmp_path, robot_file, seed) -> Path:
    t = draw_serial_truth(robot_file, np.random.default_rng(seed), noise=NOISE, seed=seed,
                          inclinometer_mount=(0.012, -0.008))
    path = tmp_path / "truth.json"
    save_truth(t, path)
    return path


def _fast_config(tmp_path, robot_file, samples: int | None = None) -> Path:
    """A station config naming the robot file (``robot_file``), axis speeds 12 times
    the default simulated station's (accelerations 96 times), the tests' snapshot timing
    and timeouts (:func:`tests.simconfig.quick_text`)."""
    path = serial_config(robot_file, tmp_path, velocity=24.0, acceleration=960.0)
    path.write_text(quick_text(path.read_text(), samples=samples))
    return path


def test_station_config_names_a_robot_file(tmp_path):
    spec = load_robot_file(HAYATI)
    c = sim_config(HAYATI)
    assert c.robot == spec.name and len(c.canopen.nodes) == 6 and c.spec == spec
    data = sim_config_data(spec)
    data["robot"] = "other"
    with pytest.raises(ConfigError, match="not the robot file's name"):
        parse_station_config(data, "x.toml", spec=spec)
    data = sim_config_data(spec)
    data["canopen"]["nodes"] = [1, 2, 3, 4]
    with pytest.raises(ConfigError, match="canopen.nodes"):
        parse_station_config(data, "x.toml", spec=spec)


def test_simulated_arm_stops_at_a_joint_limit_and_at_the_floor():
    t = draw_serial_truth(HAYATI, np.random.default_rng(3))
    clock = FakeClock()
    sim = SimulatedSerial(t, clock=clock)
    model, xi = t.model(), t.xi()
    assert sim.frame()[2, 3] > 0.1                       # starts above the floor
    q = sim.qm()
    q[5] = 3.3                                           # beyond joint 6's limit 3.1
    sim.move_to(q)
    clock.t += 100.0
    assert sim.supervise() == (5, "joint limit")
    assert 3.05 < sim.qm()[5] <= 3.1 + 1e-9
    assert sim.supervise() is None                       # stopped inside
    clock.t += 5.0
    assert sim.supervise() is None                       # at rest: nothing new to walk
    # the floor: drive towards the lowest pose of a sweep of joint 2
    q0 = sim.qm()
    sweep = np.array([q0 + np.r_[0, d, 0, 0, 0, 0] for d in np.linspace(-3, 3, 61)])
    sweep = sweep[np.all(np.abs(sweep) <= 3.1, axis=1)]
    low = sweep[np.argmin(model.frames(sweep, xi)[:, 2, 3])]
    assert model.frames(low, xi)[0, 2, 3] < 0
    sim.move_to(low)
    clock.t += 100.0
    axis, kind = sim.supervise()
    assert kind == "floor" and axis == 1
    assert 0.0 <= sim.frame()[2, 3] < 0.01               # stopped at the floor


def test_a_simulated_arm_at_rest_outside_its_range_faults_at_its_first_check():
    """The walk is skipped only at rest after a check that found the pose inside: an
    arm whose start is outside the range it is given faults without moving."""
    t = draw_serial_truth(HAYATI, np.random.default_rng(3))
    clock = FakeClock()
    sim = SimulatedSerial(t, clock=clock)
    sim.qm_range = sim.qm_range.copy()
    sim.qm_range[2, 1] = sim.qm()[2] - 0.1               # joint 3's upper end below it
    clock.t += 1.0
    assert sim.supervise() == (2, "joint limit")


def test_a_move_out_past_a_joint_limit_and_back_between_two_checks_is_caught():
    t = draw_serial_truth(HAYATI, np.random.default_rng(3))
    clock = FakeClock()
    sim = SimulatedSerial(t, clock=clock)
    q0 = sim.qm()
    assert sim.supervise() is None
    q = q0.copy()
    q[5] = 3.3                                           # beyond joint 6's limit 3.1
    sim.move_to(q)
    clock.t += 100.0
    sim.move_to(q0)                                      # and back, unchecked
    clock.t += 100.0
    assert np.allclose(sim.qm(), q0)
    assert sim.supervise() == (5, "joint limit")


def test_plan_is_safe_and_counted_from_the_identifiable_set():
    robot = load_robot_file(HAYATI)
    from calibration.robots import get_robot

    robot = get_robot(robot)
    xi = robot.nominal
    ref = serial_plan.reference_pose(robot, xi)
    n_min = serial_plan.minimum_count("sm-distance-tilt", robot, xi, ref)
    ident = serial_plan.identifiable("sm-distance-tilt", robot, xi,
                                     serial_plan.safe_pool(robot, xi, np.random.default_rng(1)),
                                     ref)
    assert not {"base_d", "base_theta", "base_a"} & set(ident)  # no base position, no heading
    assert not {f"k{i}" for i in range(1, 7)} & set(ident)     # held by the robot file
    assert {"beta2", "beta3", "a2", "a3", "distance_off"} <= set(ident)
    from calibration.identifiability import minimum_poses

    assert n_min == minimum_poses(len(ident), 3)
    targets, qm, use, design = serial_plan.plan("sm-distance-tilt", robot, xi, ref,
                                                PlanRequest(seed=4))
    assert design["poses"] == sum(u == "fit" for u in use)
    assert 0 < design["predicted_heldout"]["rms"] < 1e-4        # m, at the devices' noise
    _, _, _, rand = serial_plan.plan("sm-distance-tilt", robot, xi, ref,
                                     PlanRequest(seed=4, design="random"))
    assert rand["design"] == "random"
    assert design["predicted_heldout"]["rms"] < rand["predicted_heldout"]["rms"]
    box = serial_plan.joint_box(robot)
    assert np.all((qm >= box[:, 0]) & (qm <= box[:, 1]))
    assert np.all(targets[:, 2] >= serial_plan.FLOOR_MARGIN)
    assert sum(u == "fit" for u in use) >= n_min and sum(u == "validation" for u in use) >= 3
    here = ref
    for q in qm:
        assert serial_plan.path_clear(robot, xi, here, q)
        here = q
    steps = np.abs(np.diff(np.vstack([ref, qm]), axis=0)).sum()
    shuffled = np.abs(np.diff(np.vstack([ref, qm[np.random.default_rng(0).permutation(len(qm))]]),
                              axis=0)).sum()
    assert steps < 0.7 * shuffled                               # the travel order is short


def _session(tmp_path, robot_file, seed, count=None):
    truth_path = _truth_file(tmp_path, robot_file, seed)
    cfg = _fast_config(tmp_path, robot_file)
    from drivers.sim.truth import load_truth

    truth = load_truth(truth_path)
    with SimulatorProcess(str(robot_file), truth=str(truth_path), config=str(cfg)) as sim:
        config = sim.station_config()
        with Session(config, "sm-distance-tilt", tmp_path / "out",
                     request=PlanRequest(count=count, seed=seed)) as s:
            files = s.run()
        with sim.control() as ctl:
            state = ctl.call(state=True)
    return truth, files, s, state


def _within_family_bound(s, truth, state):
    """Every calibrated parameter of session ``s`` within its family bound of the truth
    in the session's terms (what its model reaches on noise-free readings of the truth,
    ``equivalent_truth``): ``(err / std, result)``."""
    res, model = s.outcome.result, s.outcome.model
    x_eq, left = equivalent_truth(model, res, serial_truth_vector(model, truth, state))
    ok = np.array([st.identifiable for st in res.status])
    z = (res.x - x_eq)[ok] / res.std[ok]
    assert left < 1e-3 and ok.sum() >= 25, (left, ok.sum())
    assert np.abs(z).max() < session_bound(res), np.round(z, 2)
    return z, res


@pytest.mark.heavy
def test_ur5_hayati_session_matches_the_truth_point_to_point(tmp_path):
    truth, files, s, state = _session(tmp_path, HAYATI, seed=8101, count=40)
    # every calibrated parameter within its family bound (3.6-3.9 std for 27) of the truth
    # in the session's terms; pooled over drawn arms in test_session_pooled.py
    _within_family_bound(s, truth, state)
    doc = read_params(files["params"])
    robot, xi = calibrated_model(doc)
    tr = read_trace(files["trace"])
    assert tr.header["robot_file"]["sha256"] == robot.spec.source["sha256"]
    nominal = serial_plan.point_to_point_rms(robot, robot.nominal, truth.xi(), seed=1)
    calibrated = serial_plan.point_to_point_rms(robot, xi, truth.xi(), seed=1)
    assert nominal > 1e-3
    assert calibrated < 3e-5
    assert Path(files["urdf"]).exists() and Path(files["report"]).exists()


@pytest.mark.heavy
def test_robot_file_session_resumes_exactly_after_a_kill(tmp_path, no_report):
    """Killed between the reference and the plan, mid-line and mid-poses, the robot
    file's session resumes to the uninterrupted one's readings and result
    (tests/station/test_resume.py, on a UR5-like arm)."""
    from tests.station.test_resume import Case, _check_same, _resume_after, _as_after_a_crash

    truth_path = _truth_file(tmp_path, HAYATI, seed=8203)
    cfg = _fast_config(tmp_path, HAYATI, samples=2)
    request = PlanRequest(count=16, validation=2, seed=5)
    with SimulatorProcess(str(HAYATI), truth=str(truth_path), config=str(cfg), seed=21,
                          pose_noise=True) as sim:
        config = sim.station_config()
        with sim.control() as ctl:
            start = ctl.call(state=True)["qm"]
        _as_after_a_crash(config, start)
        with Session(config, "sm-distance-tilt", tmp_path / "whole", request=request) as s:
            s.run()
        trace = read_trace(s.trace_path)
        case = Case("sm-distance-tilt", config, request, {}, start,
                    s.trace_path.read_bytes().splitlines(True),
                    {p["plan_index"]: p for p in trace.poses}, s.outcome.result.x.copy(),
                    s.outcome.result.std.copy())
        for k, partial in ((2, True), (4, False), (8, True), (len(case.lines) - 4, False)):
            records, x = _resume_after(tmp_path, case, k, partial)
            assert _check_same(case, k, records, x) < 1e-6


@pytest.mark.heavy
def test_a_pose_below_the_real_floor_faults_and_is_skipped(tmp_path, no_report, quick_retries):
    """The engineer's start value puts the arm's base 25 cm higher than it is, so some
    planned poses are below the real floor: the simulated drive faults naming the floor
    (EMCY manufacturer bytes), the session retries, skips, and completes with the rest
    (the base height is not seen by distances and tilts: the result is still right)."""
    truth_path = _truth_file(tmp_path, HAYATI, seed=8305)
    cfg = _fast_config(tmp_path, HAYATI, samples=2)
    from drivers.sim.truth import load_truth

    truth = load_truth(truth_path)
    base_d = truth.parameters["base_d"] + 0.25
    with SimulatorProcess(str(HAYATI), truth=str(truth_path), config=str(cfg)) as sim:
        with Session(sim.station_config(), "sm-distance-tilt", tmp_path / "out",
                     request=PlanRequest(count=40, validation=6, seed=2),
                     nominal={"base_d": base_d}) as s:
            files = s.run()
        with sim.control() as ctl:
            state = ctl.call(state=True)
    floor = [e for e in s.events if e["kind"] == "fault" and "FLOOR" in e["message"]]
    skips = [e for e in s.events if e["kind"] == "skip"]
    assert floor and skips, "no planned pose was below the real floor: the test proves nothing"
    assert len(s.measured) + len(s.skipped) == len(s.plan_poses)
    # right within what it states: every calibrated parameter within its family bound of
    # the truth in the session's terms (as test_ur5_hayati_session_matches_the_truth_...;
    # a fixed 50 um on the tool, asserted before, failed an honest run at 53 um: the poses
    # skipped vary run to run, and so does the session's precision)
    z, res = _within_family_bound(s, truth, state)
    robot, xi = calibrated_model(read_params(files["params"]))
    print("floor session: max |err/std|", round(float(np.abs(z).max()), 2), "bound",
          round(session_bound(res), 2), "point to point",
          serial_plan.point_to_point_rms(robot, xi, truth.xi(), seed=1))


def test_run_with_a_robot_file_needs_its_truth(tmp_path, capsys):
    import app

    assert app.main(["run", "--simulate", "--robot", str(HAYATI), "--method",
                     "sm-distance-tilt", "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "needs --truth" in err[0]
    assert app.main(["simulate", "--robot", str(tmp_path / "no-such-arm.toml")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no-such-arm.toml" in err[0]


@pytest.mark.slow
@pytest.mark.parametrize("robot_file, seed", [(DH, 8407), (HAYATI, 8509)])
def test_cli_run_on_a_ur5_like_arm(tmp_path, robot_file, seed):
    """``app.py run --simulate --robot ARM --method sm-distance-tilt --truth T`` with the
    default plan: held-out point-to-point distances well under 0.1 mm RMS from the truth's
    where the nominal's are millimetres off."""
    import subprocess
    import sys

    truth_path = _truth_file(tmp_path, robot_file, seed)
    out = tmp_path / "run"
    proc = subprocess.run([sys.executable, str(ROOT / "app.py"), "run", "--simulate", "--robot",
                           str(robot_file), "--method", "sm-distance-tilt", "--truth",
                           str(truth_path), "--out", str(out)], capture_output=True, text=True,
                          timeout=900)
    assert proc.returncode == 0, proc.stderr[-2000:]
    from drivers.sim.truth import load_truth

    truth = load_truth(truth_path)
    robot, xi = calibrated_model(read_params(out / "params.json"))
    nominal = serial_plan.point_to_point_rms(robot, robot.nominal, truth.xi(), seed=3)
    calibrated = serial_plan.point_to_point_rms(robot, xi, truth.xi(), seed=3)
    print(f"{robot.name}: point-to-point RMS nominal {nominal * 1e3:.3f} mm, calibrated "
          f"{calibrated * 1e3:.4f} mm")
    assert nominal > 1e-3 and calibrated < 3e-5
    assert (out / "calibrated.urdf").exists()


@pytest.mark.heavy
def test_sm_distance_session_on_a_robot_file(tmp_path, no_report):
    """sm-distance (draw-wire only) on the UR5-like arm: distances from the reference
    point alone calibrate the arm's shape (point to point)."""
    truth_path = _truth_file(tmp_path, HAYATI, seed=8611)
    cfg = _fast_config(tmp_path, HAYATI, samples=2)
    from drivers.sim.truth import load_truth

    truth = load_truth(truth_path)
    with SimulatorProcess(str(HAYATI), truth=str(truth_path), config=str(cfg)) as sim:
        with Session(sim.station_config(), "sm-distance", tmp_path / "out",
                     request=PlanRequest(count=90, validation=6, seed=6)) as s:
            files = s.run()
    tr = read_trace(files["trace"])
    assert tr.reference["role"] == "reference-point" and "tilt" not in tr.poses[0]
    robot, xi = calibrated_model(read_params(files["params"]))
    nominal = serial_plan.point_to_point_rms(robot, robot.nominal, truth.xi(), seed=2)
    calibrated = serial_plan.point_to_point_rms(robot, xi, truth.xi(), seed=2)
    assert nominal > 1e-3 and calibrated < 1e-4, (nominal, calibrated)


def test_the_wizard_takes_a_robot_files_station(tmp_path):
    from station.gui.controller import Controller

    cfg = _fast_config(tmp_path, HAYATI)
    assert Path(Controller.robot_of_config(None, cfg)).resolve() == HAYATI.resolve()


def test_plan_chooses_from_more_candidates_where_ways_are_blocked():
    """Seed 0, 30 poses: the D-optimal 1.3 x 30 candidates leave too few with a clear
    way there; the plan chooses again from more instead of giving up."""
    from calibration.robots import get_robot

    robot = get_robot(load_robot_file(HAYATI))
    ref = serial_plan.reference_pose(robot, robot.nominal)
    _, qm, use, _ = serial_plan.plan("sm-distance-tilt", robot, robot.nominal, ref,
                                     PlanRequest(count=30, seed=0))
    assert use.count("fit") == 30 and use.count("validation") == 6
    here = ref
    for q in qm:
        assert serial_plan.path_clear(robot, robot.nominal, here, q)
        here = q
