"""Guided touching sessions (sm-plane, sm-self-redundancy; report 7.4, 7.3).

The simulator runs in its own process; the simulated operator
(``station.simulation.touch_operator``) sees the contact through the simulator's control port
and jogs the robot through the session, as an operator with a feeler gauge
would. The influence parameters the report takes as known (sm-plane: L4,
theta0, a0 and the plane; sm-self-redundancy: L4) are given their true values
as start values; every identifiable parameter must come out within its family
bound of the unseen truth (``test_session.session_bound``: 3.3 std for 10 normal errors, more at few degrees of freedom).
"""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from calibration.robots import get_robot
from drivers.config import load_station_config
from drivers.sim.server import SimulatorProcess
from drivers.sim.truth import load_truth
from station.planning import arm_plan
from station.outputs.params_file import read_params
from station.planning.request import MUST_KNOW, PlanRequest
from station.recording.planned_pose import PlannedPose
from station.session.session import Session
from station.simulation.touch_operator import SimulatedOperator
from station.recording.trace import read_trace
from tests.station.test_session import _identifiable_within, _session_config, fast_config

ROOT = Path(__file__).resolve().parents[2]
FIX = ROOT / "fixtures"
UNSEEN = FIX / "truth" / "agebot-sm-unseen.json"
SM = get_robot("agebot-sm")
PLANE = ("plane_a", "plane_b", "plane_c")


def _known(truth, names):
    xi = truth.xi()
    out = {n: float(xi[SM.index(n)]) for n in names if n not in PLANE}
    if any(n in PLANE for n in names):
        out.update(zip(PLANE, truth.plane))
    return out


def test_sm_plane_session_touches_the_plane_and_recovers_the_unseen_truth(tmp_path):
    cfg = fast_config(tmp_path, "agebot-sm")
    truth = load_truth(UNSEEN)
    known = _known(truth, MUST_KNOW["sm-plane"])
    with SimulatorProcess("agebot-sm", truth=str(UNSEEN), config=str(cfg), seed=3) as sim:
        with sim.control() as ctl, sim.control() as faults:
            injected = []

            def observer(kind, payload):      # a drive fault in the middle of touching
                if (kind == "progress" and payload.message.startswith("touching")
                        and payload.done == 4 and not injected):
                    faults.call(faults={"drive_fault_node": 3})
                    injected.append(payload.pose.index)

            op = SimulatedOperator(ctl)
            with Session(_session_config(sim, cfg), "sm-plane", tmp_path / "run", nominal=known,
                         touch=op, observer=observer,
                         request=PlanRequest(count=20, validation=3, seed=1)) as s:
                files = s.run()
    assert injected
    trace = read_trace(files["trace"])
    kinds = [e["kind"] for e in trace.events]
    assert "fault" in kinds and "retry" in kinds and "skip" not in kinds
    assert len(trace.fit_poses) == 20 and len(trace.validation_poses) == 3
    assert len({p["plan_index"] for p in trace.current_poses}) == 23
    # a contact records qm only; the plane the engineer gave is in the header
    assert all("distance" not in p and "tilt" not in p for p in trace.poses)
    assert [trace.header["nominal"][k] for k in PLANE] == list(truth.plane)
    # every recorded contact really touches the true plane (within the operator's 1e-6 m)
    n = np.array(truth.plane)
    qm = np.array([p["qm"] for p in trace.poses])
    dist = (SM.fk(qm, truth.xi())[:, :3] @ n + 1.0) / np.linalg.norm(n)
    assert np.abs(dist).max() < 1.5e-6
    res = s.outcome.result
    assert res.converged and res.n_identifiable == 10
    assert not _identifiable_within(res, np.r_[truth.xi(), n], list(SM.param_names) + list(PLANE))
    (val,) = s.validation
    assert val["channel"] == "plane" and val["unit"] == "m" and val["n"] == 3
    assert val["rms_after"] < 2e-6 and val["rms_after"] < val["rms_before"] / 1000
    assert read_params(files["params"])["method"] == "sm-plane"


def _drop_last_pose_line(path: Path) -> dict:
    """A crash between the two lines of a pair: the pair's second pose never written."""
    lines = path.read_bytes().splitlines(keepends=True)
    k = max(i for i, ln in enumerate(lines) if b'"record":"pose"' in ln)
    path.write_bytes(b"".join(lines[:k] + lines[k + 1:]))
    return json.loads(lines[k])


@pytest.mark.heavy
def test_sm_self_redundancy_pairs_resume_and_skip_whole(tmp_path):
    cfg = fast_config(tmp_path, "agebot-sm")
    truth = load_truth(UNSEEN)
    known = _known(truth, MUST_KNOW["sm-self-redundancy"])
    out = tmp_path / "run"
    req = PlanRequest(count=12, validation=2, seed=2)
    with SimulatorProcess("agebot-sm", truth=str(UNSEEN), config=str(cfg), seed=5) as sim:
        config = _session_config(sim, cfg)
        with sim.control() as ctl, sim.control() as faults:
            # 1. the operator stops halfway through the third pair
            def stop(kind, payload):
                if kind == "progress" and payload.readings and payload.done == 5:
                    first.abort()

            with Session(config, "sm-self-redundancy", out, nominal=known, observer=stop,
                         touch=SimulatedOperator(ctl), request=req) as first:
                with pytest.raises(Exception, match="aborted"):
                    first.run()
                assert len(first.measured) == 4                 # the touched pose is not written
            # ... and the process died between the two lines of the second pair
            lost = _drop_last_pose_line(out / "trace.jsonl")

            # 2. resumed with a new operator (it finds the mark again at the recorded first
            # pose); a drive fault at a second pose answered "skip" drops the whole pair
            injected = []

            def fault(kind, payload):
                p = payload.pose if kind == "progress" else None
                if (p is not None and payload.message.startswith("touching") and p.group == 6
                        and p.index != again.group_of(p)[0].index and not injected):
                    faults.call(faults={"drive_fault_node": 2})
                    injected.append(p.index)

            with Session(config, "sm-self-redundancy", out, observer=fault,
                         touch=SimulatedOperator(ctl), request=req,
                         fault_policy=lambda pose, err, attempt: "skip") as again:
                assert again.resumed and len(again.measured) == 3
                assert lost["plan_index"] in {p.index for p in again.pending}
                files = again.run()
    assert injected
    trace = read_trace(files["trace"])
    group = {p.index: p.group for p in again.plan_poses}
    skips = [e for e in trace.events if e["kind"] == "skip"]
    # pair 6 by the fault; a pair whose mark the arm cannot reach at the second phi
    # (the operator gives up: "no contact") goes whole too
    assert all("no contact" in e["message"] or group[e["plan_index"]] == 6
               or "pair partner" in e["message"] for e in skips)
    gone = {group[e["plan_index"]] for e in skips}
    assert 6 in gone and len(gone) <= 3
    assert sorted(e["plan_index"] for e in skips) == sorted(i for i, g in group.items()
                                                            if g in gone)
    groups: dict[int, list] = {}
    for p in trace.current_poses:      # a reading measured again: its newest
        groups.setdefault(p["group"], []).append(p)
    assert set(groups) == set(range(14)) - gone and all(len(g) == 2 for g in groups.values())
    assert len({p["plan_index"] for p in trace.current_poses}) == len(trace.current_poses)
    assert any(e["kind"] == "resume" for e in trace.events)
    # both poses of every pair touch the same true point (x, y), at phi of both signs
    for g in groups.values():
        X = SM.fk(np.array([p["qm"] for p in g]), truth.xi())
        assert np.linalg.norm(X[0, :2] - X[1, :2]) < 1.5e-6
        assert abs(X[0, 3] - X[1, 3]) > np.radians(10)
    res = again.outcome.result
    assert res.converged and res.n_identifiable == 7
    assert not _identifiable_within(res, truth.xi(), list(SM.param_names))
    val = {v["channel"]: v for v in again.validation}
    assert set(val) == {"dx", "dy"} and val["dx"]["n"] >= 1
    assert all(v["unit"] == "m" and v["rms_after"] < 2e-6 for v in val.values())


@pytest.mark.heavy
def test_app_run_simulate_sm_plane_from_the_command_line(tmp_path):
    cfg = fast_config(tmp_path, "agebot-sm")
    out = tmp_path / "run"
    cmd = [sys.executable, str(ROOT / "app.py"), "run", "--simulate", "--robot", "agebot-sm",
           "--method", "sm-plane", "--out", str(out), "--config", str(cfg), "--count", "18",
           "--seed", "3", "--sim-seed", "4"]
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert "taken from the simulator's truth file" in done.stdout
    truth = load_truth(FIX / "truth" / "agebot-sm.json")      # the default simulated robot
    header = read_trace(out / "trace.jsonl").header
    assert [header["nominal"][k] for k in PLANE] == list(truth.plane)
    assert header["nominal"]["L4"] == truth.parameters["L4"]
    doc = read_params(out / "params.json")
    assert doc["method"] == "sm-plane" and (out / "report.html").exists()
    # without --simulate there is no operator: refused in one line, nothing written
    real = subprocess.run([sys.executable, str(ROOT / "app.py"), "run", "--robot", "agebot-sm",
                           "--method", "sm-plane", "--config", str(cfg),
                           "--out", str(tmp_path / "real")], capture_output=True, text=True,
                          timeout=60)
    assert real.returncode != 0 and "guided touching" in real.stderr
    assert len(real.stderr.strip().splitlines()) == 1 and not (tmp_path / "real").exists()


def test_touch_plans_and_refusals(tmp_path):
    """Planning without devices: pairs at one x, y, z with phi of both signs, held out
    whole; contacts on the given plane, approached from 2 cm on the base's side. A
    session refuses sm-plane without the plane and a touching session without an
    operator; sm-full-pose is still refused."""
    nom = SM.params({"L4": 0.86})
    poses = arm_plan.plan_sm("sm-self-redundancy", nom, None,
                            PlanRequest(count=6, validation=2, seed=4))
    assert len(poses) == 16 and [p.index for p in poses] == list(range(16))
    for a, b in zip(poses[::2], poses[1::2]):
        assert a.group == b.group and a.use == b.use
        assert a.target[:3] == b.target[:3] and a.target[3] < 0 < b.target[3]
    assert sum(p.use == "validation" for p in poses) == 4
    assert PlannedPose.from_record(poses[3].record()) == poses[3]
    plane = np.array([-0.2, -0.61, 0.05])
    contacts = arm_plan.plan_sm("sm-plane", nom, None, PlanRequest(count=8, validation=2),
                               plane=plane)
    assert len(contacts) == 10 and all(p.group is None for p in contacts)
    X = np.array([p.target for p in contacts])
    np.testing.assert_allclose(X[:, :3] @ plane + 1.0, 0.0, atol=1e-12)
    A = SM.fk(np.array([p.qm for p in contacts]), nom)
    np.testing.assert_allclose((A[:, :3] @ plane + 1.0) / np.linalg.norm(plane), 0.02, rtol=1e-6)

    config = load_station_config(FIX / "stations" / "sim-sm.toml")
    with Session(config, "sm-plane", tmp_path / "a") as s:
        with pytest.raises(Exception, match="plane_a, plane_b, plane_c"):
            s.plan()
        with pytest.raises(Exception, match="touch callback"):
            s.run()
    with pytest.raises(Exception, match="pose tracker"):
        Session(config, "sm-full-pose", tmp_path / "b")
