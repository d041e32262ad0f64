"""A URDF robot calibrated at the simulated station with a motion capture (``sm-markers``):
whole sessions against the simulator in its own process (its true URDF, the room's
``[mocap]``), judged by the calibrated points' predictions against the truth
(:mod:`station.simulation.urdf_scores`), and the faults of a motion capture: a session
killed and resumed, a marker occluded, the connection dropped, frames late.

The station config of these tests (:func:`station.simulation.urdf_sessions.urdf_config`)
has axes 12 times the default simulated station's, the tests' snapshot timing and few
frames per reading: a short session takes some 15 s on 2 cores.
"""
from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from calibration.robots import get_robot
from drivers.robot_file import urdf_ref
from drivers.sim.server import SimulatorProcess
from drivers.sim.truth import load_truth, save_truth
from drivers.sim.urdf_truth import frame_matrix, true_points
from drivers.urdf_file import load_urdf
from station.outputs.params_file import read_params
from station.planning.request import PlanRequest
from station.recording.trace import read_trace
from station.simulation import urdf_scores
from station.simulation.urdf_sessions import (
    run_urdf_session,
    truth_beside,
    urdf_config,
    urdf_truth,
)
from tests.station.test_cli import app

ROOT = Path(__file__).resolve().parents[2]
URDF = ROOT / "fixtures" / "robots" / "m10ia-like.urdf"
REF = urdf_ref(URDF, "base_link", "tool0")
SPEED, FRAMES = 12.0, 3          # the tests' station: faster axes, 3 frames a reading
#: a short session: a few poses more than eq. 60's 19 for the 33 identifiable
SHORT = {"count": 22, "validation": 3}


def _station(tmp_path: Path, seed: int, **config) -> tuple[Path, Path, object]:
    """``(truth file, station config, truth)`` of a robot drawn with ``seed`` in
    ``tmp_path`` (the tests' timing, :data:`SPEED`, :data:`FRAMES`)."""
    truth, _x = urdf_truth(REF, seed, f"tests/station/test_urdf_session.py, seed {seed}")
    path = tmp_path / "truth.json"
    truth = truth_beside(truth, path)
    save_truth(truth, path)
    cfg = urdf_config(truth, REF, tmp_path, speed=SPEED, **({"frames": FRAMES} | config))
    return path, cfg, load_truth(path)


def _session(sim, cfg, out, **kw):
    from drivers.config import load_station_config
    from drivers.endpoints import with_endpoints
    from station.session.session import Session

    return Session(with_endpoints(load_station_config(cfg), sim.endpoints, source="simulator"),
                   "sm-markers", out, **kw)


def _score(session, truth) -> urdf_scores.UrdfScore:
    score = urdf_scores.UrdfScore(seed=truth.seed or 0, completed=True)
    return urdf_scores.score_document(score, session.outcome.document, truth, count=60)


# -- fast ---------------------------------------------------------------------------------

@pytest.mark.heavy
def test_a_short_session_runs_to_a_parameter_file_and_a_calibrated_urdf(tmp_path, no_report):
    truth, _x = urdf_truth(REF, 3, "a short session")
    sc = run_urdf_session(truth, REF, tmp_path, seed=3, speed=SPEED, frames=FRAMES,
                          request=PlanRequest(seed=3, **SHORT), count=60)
    assert sc.completed, sc.error
    out = tmp_path / "run"
    doc = read_params(out / "params.json")
    assert doc["method"] == "sm-markers" and doc["fit"]["quality"]["passed"]
    assert set(doc["points_on_tool"]) == {"point1", "point2", "point3"}
    # calibrated.urdf: the robot's own URDF with its joints' origins calibrated (its
    # names, links and the rest as written); with the parameter file's measurement frame
    # and points on the tool it puts the points where the calibration predicts them
    text = (out / "calibrated.urdf").read_text()
    assert 'name="flange-tool0"' in text and "hardwareInterface" in text
    spec = load_urdf(out / "calibrated.urdf", "base_link", "tool0")
    assert [j.name for j in spec.joints] == [f"joint_{i}" for i in range(1, 7)]
    cal = get_robot(spec)
    qm = urdf_scores.score_poses(cal, 20)
    mf = doc["urdf"]["measurement_frame"]
    T = np.einsum("ij,mjk->mik", frame_matrix((mf["xyz"], mf["rpy"])), cal.frames(qm, cal.nominal))
    u = np.array([doc["points_on_tool"][f"point{j}"]["xyz"] for j in (1, 2, 3)])
    p = T[:, None, :3, 3] + np.einsum("mij,kj->mki", T[:, :3, :3], u)
    assert np.abs(p - urdf_scores.predictions(doc, qm)[0]).max() < 1e-9
    # scout, middle round, last round (SHORT's fit poses and held-out ones)
    plans = [e for e in read_trace(out / "trace.jsonl").events if e["kind"] == "plan"]
    assert [e["markers_round"] for e in plans] == [0, 1, 2]
    assert sum(p["use"] == "validation" for p in plans[-1]["poses"]) == SHORT["validation"]
    assert sc.skipped == 0 and sc.poses == sum(len(e["poses"]) for e in plans)   # all seen
    # the points where the truth has them, within their reported uncertainty
    assert sc.heldout < 2e-4 and sc.error_rms < 1e-4, (sc.heldout, sc.error_rms)
    assert sc.whitened_rms < 3.0, sc.whitened_rms


def test_truth_draw_of_a_urdf_writes_the_truth_and_the_true_urdf(tmp_path):
    out = tmp_path / "truth.json"
    r = app("truth", "draw", "--robot", str(URDF), "--base-link", "base_link", "--tip-link",
            "tool0", "--seed", "4", "--out", str(out))
    assert r.returncode == 0, r.stderr
    true_urdf = out.parent / "truth-true.urdf"
    assert true_urdf.is_file() and f"--truth {out}" in r.stdout
    assert true_urdf.read_text() != URDF.read_text()
    t = load_truth(out)
    assert t.robot == "urdf" and t.robot_file == "truth-true.urdf" and len(t.points) == 3
    assert t.seed == 4 and t.noise["marker"] > 0
    # the simulator accepts it (its default station: the room of the truth) and sees
    # the truth's points on the tool
    with SimulatorProcess(REF, truth=str(out), seed=4) as sim:
        assert "mocap" in sim.endpoints
        with sim.control() as ctl:
            state = ctl.call(state=True)
    want = true_points(t, t.model(), t.xi(), np.array(state["qm"]))
    assert np.allclose(state["points"], want, atol=1e-9)


def test_a_truth_of_another_robot_is_refused_in_one_line(tmp_path):
    chain = ["--robot", str(URDF), "--base-link", "base_link", "--tip-link", "tool0"]
    other = ROOT / "fixtures" / "truth" / "agebot-sm.json"
    r = app("run", "--simulate", *chain, "--method", "sm-markers", "--truth", str(other),
            "--out", str(tmp_path / "s"))
    assert r.returncode == 2, r.stderr
    line, = r.stderr.strip().splitlines()
    assert line.startswith("error: ") and "not of the URDF robot" in line and "agebot-sm" in line
    # a robot file's arm: not this robot either
    from station.simulation.serial_sessions import serial_truth

    arm = serial_truth(ROOT / "fixtures" / "robots" / "ur5-like-hayati.toml", 1, "an arm")
    save_truth(arm, tmp_path / "arm.json")
    r = app("run", "--simulate", *chain, "--method", "sm-markers", "--truth",
            str(tmp_path / "arm.json"), "--out", str(tmp_path / "s2"))
    assert r.returncode == 2, r.stderr
    line, = r.stderr.strip().splitlines()
    assert "not of the URDF robot" in line and arm.robot in line and "Traceback" not in r.stderr
    assert not (tmp_path / "s").exists() and not (tmp_path / "s2" / "trace.jsonl").exists()


def test_the_score_of_the_truth_itself_is_zero_error(tmp_path):
    """The scoring on a parameter file holding the truth: no error, and the reported
    covariance of the predictions is ``J C J^T`` (checked against finite differences)."""
    from calibration.methods.sm_markers import marker_names
    from drivers.robot_file import load_robot_file

    truth, x = urdf_truth(REF, 2, "scored")
    robot = get_robot(load_robot_file(REF))
    names = list(marker_names(3))
    params = {n: {"value": float(v)} for n, v in zip(robot.param_names, x)}
    params |= {n: {"value": float(v)} for n, v in zip(names, np.ravel(truth.points))}
    cov_names = ["base_x", "j2_y", "q3_off", "marker2_z"]
    C = np.diag([1e-8, 4e-8, 1e-8, 9e-8])
    doc = {"method": "sm-markers", "robot_file": dict(robot.spec.source), "parameters": params,
           "covariance": {"names": cov_names, "matrix": C.tolist()}}
    sc = urdf_scores.score_document(urdf_scores.UrdfScore(seed=2, completed=True), doc, truth,
                                    count=5)
    assert sc.e.shape == (5, 3, 3) and np.abs(sc.e).max() < 1e-12
    qm = urdf_scores.score_poses(robot, 5)
    p0, cov = urdf_scores.predictions(doc, qm)
    J = []
    for n in cov_names:
        d = json.loads(json.dumps(doc))
        d["parameters"][n]["value"] += 1e-7
        J.append((urdf_scores.predictions(d, qm)[0] - p0) / 1e-7)
    J = np.stack(J, axis=-1)
    assert np.allclose(cov, np.einsum("kmia,ab,kmjb->kmij", J, C, J), rtol=1e-4, atol=1e-16)


# -- slow (CI) -------------------------------------------------------------------------------

def _round2_poses(trace: Path) -> int:
    """Poses recorded after round 2 was planned (0 before it)."""
    try:
        lines = trace.read_bytes().splitlines()
    except FileNotFoundError:
        return 0
    start = next((k for k, line in enumerate(lines) if b'"markers_round":2' in line), None)
    return 0 if start is None else sum(b'"record":"pose"' in line for line in lines[start:])


def _predicted(params: Path, qm):
    return urdf_scores.predictions(read_params(params), qm)


@pytest.mark.slow
def test_sigkill_in_round_2_resumes_to_the_same_result(tmp_path):
    """``app.py run`` killed with SIGKILL while it measures round 2 resumes from its trace
    (no pose measured twice, none lost) and calibrates exactly what the trace holds; an
    uninterrupted session on the same simulated robot predicts the same points within
    their reported uncertainty (compared by their predictions: the held parameters are
    estimated from each session's own scout)."""
    from station.fitting.batch import calibrate

    truth_path, cfg, _truth = _station(tmp_path, 5)
    with SimulatorProcess(REF, truth=str(truth_path), config=str(cfg), seed=21) as sim:
        ep = tmp_path / "endpoints.json"
        ep.write_text(json.dumps(sim.endpoints))
        cmd = [sys.executable, str(ROOT / "app.py"), "run", "--robot", str(URDF), "--base-link",
               "base_link", "--tip-link", "tool0", "--method", "sm-markers", "--config",
               str(cfg), "--endpoints", str(ep), "--count", "22", "--seed", "5"]
        killed = tmp_path / "killed"
        p = subprocess.Popen(cmd + ["--out", str(killed)], stdout=subprocess.DEVNULL,
                             stderr=subprocess.PIPE)
        deadline = time.monotonic() + 120
        while _round2_poses(killed / "trace.jsonl") < 4:
            assert p.poll() is None, p.stderr.read().decode()
            assert time.monotonic() < deadline, "the session did not reach round 2"
            time.sleep(0.05)
        os.kill(p.pid, signal.SIGKILL)
        p.wait()
        p.stderr.close()
        partial = read_trace(killed / "trace.jsonl")            # never corrupted
        n_before = len(partial.poses)
        assert not (killed / "params.json").exists()

        done = subprocess.run(cmd + ["--out", str(killed)], capture_output=True, text=True,
                              timeout=180)
        assert done.returncode == 0, done.stderr
        assert "resuming the session" in done.stdout
        whole = subprocess.run(cmd + ["--out", str(tmp_path / "whole")], capture_output=True,
                               text=True, timeout=180)
        assert whole.returncode == 0, whole.stderr

    resumed = read_trace(killed / "trace.jsonl")
    idx = [p["plan_index"] for p in resumed.current_poses]
    assert len(idx) == len(set(idx))                                 # nothing measured twice
    assert [p["qm"] for p in resumed.poses[:n_before]] == [p["qm"] for p in partial.poses]
    assert any(e["kind"] == "resume" for e in resumed.events)
    planned = {p["index"] for e in resumed.events if e["kind"] == "plan" for p in e["poses"]}
    skipped = {e["plan_index"] for e in resumed.events if e["kind"] == "skip"}
    assert set(idx) | skipped == planned                             # none lost
    a = read_params(killed / "params.json")
    again = calibrate(read_trace(killed / "trace.jsonl")).result     # exactly its trace
    for name, pa in a["parameters"].items():
        assert pa["value"] == pytest.approx(again.value(name), rel=1e-9, abs=1e-12), name
    # the same robot within the noise, by the points predicted anywhere in the limits
    qm = urdf_scores.score_poses(_robot(), 100, seed=1)
    pa, ca = _predicted(killed / "params.json", qm)
    pb, cb = _predicted(tmp_path / "whole" / "params.json", qm)
    d = pa - pb
    d2 = np.einsum("kmi,kmi->km", d, np.linalg.solve(ca + cb, d[..., None])[..., 0])
    assert math.sqrt(np.mean(d2 / 3)) < 2.5 and np.abs(d).max() < 2e-4, np.sqrt(d2.max())


def _robot():
    from drivers.robot_file import load_robot_file

    return get_robot(load_robot_file(REF))


def _faulted_session(tmp_path, seed: int, on_progress=None, on_event=None, **config):
    """A short session in-process with an observer that injects faults through the
    simulator's control port: ``on_progress(ctl, stage, done)`` after each pose measured,
    ``on_event(ctl, event)`` at each event. Returns ``(session, truth, mocap)``: the
    motion capture's name and reconnections at the end."""
    truth_path, cfg, truth = _station(tmp_path, seed, **config)
    with SimulatorProcess(REF, truth=str(truth_path), config=str(cfg), seed=seed) as sim:
        with sim.control() as ctl:
            def observer(kind, payload):
                if kind == "progress" and payload.readings and on_progress is not None:
                    on_progress(ctl, payload.stage, payload.stage_done)
                elif kind == "event" and on_event is not None:
                    on_event(ctl, payload)

            with _session(sim, cfg, tmp_path / "run", observer=observer,
                          request=PlanRequest(seed=seed, **SHORT)) as s:
                s.run()
                mocap = {"name": s.rig.mocap.name, "reconnects": s.rig.mocap.reconnects}
    return s, truth, mocap


@pytest.mark.slow
def test_an_occluded_marker_leaves_poses_with_fewer_points(tmp_path, no_report):
    """One label occluded for a few poses of round 2: the session goes on, those poses
    record the other points (``null`` for it), and the calibration passes."""
    occluded = []

    def on_progress(ctl, stage, done):
        if stage == "round 2" and done == 2:
            ctl.call(mocap={"occluded": ["tool2"]})
            occluded.append(done)
        elif stage == "round 2" and done == 6:
            ctl.call(mocap={"occluded": []})

    s, truth, _ = _faulted_session(tmp_path, 6, on_progress)
    assert occluded
    poses = read_trace(s.out / "trace.jsonl").current_poses
    fewer = [p for p in poses if p["markers"][1] is None]
    assert len(fewer) == 4, [p["markers"] for p in fewer]
    assert all(p["markers"][0] is not None and p["markers"][2] is not None for p in fewer)
    doc = read_params(s.out / "params.json")
    assert doc["fit"]["quality"]["passed"]
    assert doc["fit"]["poses"] == sum(p.get("use", "fit") == "fit" for p in poses)
    sc = _score(s, truth)
    assert sc.error_rms < 1e-4 and sc.whitened_rms < 3.0, (sc.error_rms, sc.whitened_rms)


@pytest.mark.slow
def test_a_dropped_connection_is_reconnected_and_the_session_completes(tmp_path, quick_retries,
                                                                      no_report):
    """QTM closes the connection at the next request (``drop_next``) in round 2: the pose's
    reading fails (a fault event naming the motion capture), the rig's recovery opens the
    devices anew (:meth:`drivers.rig.Rig.recover`), the pose is measured on the retry and
    the session completes with every planned pose."""
    dropped = []

    def on_progress(ctl, stage, done):
        if stage == "round 2" and done == 3 and not dropped:
            ctl.call(mocap={"drop_next": True})
            dropped.append(done)

    s, _truth, mocap = _faulted_session(tmp_path, 7, on_progress)
    assert dropped and s.outcome is not None
    events = read_trace(s.out / "trace.jsonl").events
    faults = [e for e in events if e["kind"] == "fault"]
    assert len(faults) == 1 and faults[0]["device"] == mocap["name"], faults
    retry = [e for e in events if e["kind"] == "retry"]
    assert len(retry) == 1 and retry[0]["plan_index"] == faults[0]["plan_index"]
    assert faults[0]["plan_index"] in s.measured                      # measured on the retry
    assert not [e for e in events if e["kind"] in ("lost", "abort")]
    assert not [e for e in events if e["kind"] == "skip" and e.get("reason") != "dropped"]
    planned = sum(len(e["poses"]) for e in events if e["kind"] == "plan")
    assert len(s.measured) + len(s.skipped) == planned
    assert read_params(s.out / "params.json")["fit"]["quality"]["passed"]


@pytest.mark.slow
def test_frames_later_than_the_timeout_are_retried(tmp_path, quick_retries, no_report):
    """QTM answers every frame 1 s late (the config's timeout 0.3 s) from a pose of round 1
    until the first fault: that pose's reading times out, a fault event says so, and the
    pose is measured again once frames come in time."""
    late = []

    def on_progress(ctl, stage, done):
        if stage == "round 1" and done == 2 and not late:
            ctl.call(mocap={"late_s": 1.0})
            late.append(done)

    def on_event(ctl, event):
        if event["kind"] == "fault" and late and len(late) == 1:
            ctl.call(mocap={"late_s": 0.0})
            late.append(event)

    s, _truth, mocap = _faulted_session(tmp_path, 8, on_progress, on_event, timeout=0.3)
    assert len(late) == 2
    fault = late[1]
    assert fault["device"] == mocap["name"] and "0.3 s" in fault["message"], fault
    events = read_trace(s.out / "trace.jsonl").events
    assert [e["kind"] for e in events].count("fault") == 1
    assert any(e["kind"] == "retry" and e.get("plan_index") == fault["plan_index"]
               for e in events)
    assert fault["plan_index"] in s.measured
    assert read_params(s.out / "params.json")["fit"]["quality"]["passed"]


#: the Monte Carlo of CI: sessions (the bench runs 20: bench/bench_urdf_sessions.py)
MC_SESSIONS = 6


@pytest.mark.slow
def test_monte_carlo_the_reported_uncertainty_is_honest(tmp_path, no_report):
    """Sessions on drawn robots (seeds 1..MC_SESSIONS): none refused, every one passes,
    and the whitened errors of the predicted points pool to an RMS within 0.8-1.3."""
    scores = []
    for seed in range(1, MC_SESSIONS + 1):
        truth, _x = urdf_truth(REF, seed, "Monte Carlo")
        scores.append(run_urdf_session(truth, REF, tmp_path / f"s{seed}", seed=seed,
                                       speed=SPEED, frames=FRAMES,
                                       request=PlanRequest(seed=seed)))
    s = urdf_scores.summary(scores)
    assert s["refused"] == 0 and s["failed"] == 0, [sc.error for sc in scores]
    assert 0.8 <= s["whitened_rms"] <= 1.3, s
    assert s["coverage95"] > 0.8, s
