"""Issue 40: a session measures again what the gate flags before it refuses.

A reading disturbed at one pose (the simulator's ``glitch_qm``: a cable brushing the
wire there) is flagged by the gate at the end of measuring, measured again at the robot
(approached again, slower), both readings stay in the trace, and the calibration is the
one an undisturbed session gives; a disturbance that is there however the pose is
approached is confirmed by measuring again, and only then judged by the gate. A session
killed while it measures again resumes exactly.
"""
from __future__ import annotations

import dataclasses
import json
import warnings
from pathlib import Path

import numpy as np
import pytest

from calibration.errors import CalibrationError
from drivers.config import load_station_config
from drivers.endpoints import with_endpoints
from drivers.sim.server import SimulatorProcess
from station.planning.request import PlanRequest
from station.recording.trace import read_trace
from station.session.confirmation import MAX_REMEASURE
from station.session.session import Session
from tests.simconfig import quick_config

# every pose planned at once (the disturbed one is known before measuring)
REQUEST = PlanRequest(count=24, validation=4, seed=6, grow=False)
GLITCH_M = 5e-4              # 50 times the simulated draw-wire's noise


@dataclasses.dataclass
class Run:
    session: Session
    lines: list[bytes]
    disturbed: int | None = None        # the plan index of the disturbed pose


def _session(sim, cfg, folder, request=REQUEST, **kw) -> Session:
    config = with_endpoints(load_station_config(cfg), sim.endpoints, source="simulator")
    return Session(config, "sm-distance-tilt", folder, request=request, **kw)


def _run(sim, cfg, folder: Path, *, glitch: dict | None = None, accept=False) -> Run:
    """A whole session; with ``glitch``, the readings of the third fit pose disturbed."""
    disturbed = None
    with sim.control() as ctl:
        ctl.call(clear=True)
        with _session(sim, cfg, folder, accept_poor_fit=accept) as s:
            s.connect()
            s.move_to(s.reference_target()[0])
            s.capture_reference()
            s.plan()
            if glitch is not None:
                pose = [p for p in s.plan_poses if p.use == "fit"][2]
                disturbed = pose.index
                ctl.call(faults={"glitch_qm": [float(q) for q in pose.qm], **glitch})
            try:
                s.run()
            finally:
                ctl.call(clear=True)
    return Run(s, s.trace_path.read_bytes().splitlines(True), disturbed)


def _readings(run: Run, plan_index: int) -> list[dict]:
    return [p for p in read_trace(run.session.trace_path).poses
            if p.get("plan_index") == plan_index]


@pytest.fixture(scope="module")
def station(tmp_path_factory):
    folder = tmp_path_factory.mktemp("remeasure")
    cfg = quick_config(folder / "station", "agebot-sm")
    with SimulatorProcess("agebot-sm", config=str(cfg), seed=31, pose_noise=True) as sim:
        yield sim, cfg, folder


@pytest.mark.heavy
def test_a_disturbed_reading_is_measured_again_and_the_calibration_is_the_undisturbed_one(
        station, no_report):
    sim, cfg, folder = station
    clean = _run(sim, cfg, folder / "clean")
    got = _run(sim, cfg, folder / "disturbed", glitch={"glitch_distance_m": GLITCH_M})
    s, k = got.session, got.disturbed
    first, again = _readings(got, k)
    # both readings in the trace: the first 0.5 mm off the undisturbed one, the second
    # the pose as it is (another draw of the noise: approached again, slower)
    before = clean.session.measured[k]
    assert first["distance"] - before["distance"] == pytest.approx(GLITCH_M, abs=1e-6)
    assert again["remeasure_of"] == first["index"] and "remeasure_of" not in first
    assert abs(again["distance"] - before["distance"]) < 1e-4
    np.testing.assert_allclose(again["qm"], before["qm"], atol=1e-5)
    # the reason before the move, the newest reading in the calibration, the earlier set aside
    said = [e for e in s.events if e["kind"] == "remeasure"]
    assert len(said) == 1 and said[0]["plan_index"] == k and said[0]["pose"] == first["index"]
    assert "outlier" in said[0]["reason"] and "distance" in said[0]["reason"]
    trace = read_trace(s.trace_path)
    assert trace.remeasured == {first["index"]: again["index"]}
    assert again in trace.fit_poses and first not in trace.fit_poses + trace.validation_poses
    # only that pose measured again; the calibration is the undisturbed session's
    assert [p["plan_index"] for p in trace.poses].count(k) == 2
    assert len(trace.poses) == len(read_trace(clean.session.trace_path).poses) + 1
    q = s.outcome.quality
    assert q.passed and not q.outliers, q.lines()
    assert [c["readings"] for c in q.checks if c["check"] == "remeasured"] == [
        [[first["index"], again["index"]]]]
    # (one reading of 28 drawn again: the parameters move by 0.36 of their std at most)
    a, b = clean.session.outcome.result, s.outcome.result
    assert a.names == b.names
    ok = np.isfinite(a.std)
    assert np.max(np.abs(b.x - a.x)[ok] / a.std[ok]) < 0.5
    assert np.allclose(b.std[ok], a.std[ok], rtol=0.1)


@pytest.mark.heavy
def test_what_measuring_again_confirms_is_judged_by_the_gate(station, no_report):
    """The wire rubbing on an edge at one pose: every reading there is off, however the
    pose is approached. It is measured again the most times, a ``confirmed`` event says
    so, and the gate judges the newest reading (here: an outlier it leaves out)."""
    sim, cfg, folder = station
    got = _run(sim, cfg, folder / "confirmed", accept=True,
               glitch={"glitch_distance_m": GLITCH_M, "glitch_persists": True})
    s, k = got.session, got.disturbed
    readings = _readings(got, k)
    assert len(readings) == 1 + MAX_REMEASURE
    assert all(r["remeasure_of"] == p["index"] for p, r in zip(readings, readings[1:]))
    kinds = [e["kind"] for e in s.events if e.get("plan_index") == k]
    assert kinds.count("remeasure") == MAX_REMEASURE and kinds.count("confirmed") == 1
    confirmed = next(e for e in s.events if e["kind"] == "confirmed")
    assert confirmed["pose"] == readings[-1]["index"] and "the robot confirms" in \
        confirmed["message"]
    assert [o["pose"] for o in s.outcome.quality.outliers] == [readings[-1]["index"]]


@pytest.mark.heavy
def test_a_session_killed_while_it_measures_again_resumes_exactly(station, no_report):
    """Cut the disturbed session's trace after its ``remeasure`` event (the arm was on its
    way) and in the middle of the reading measured again: the resumed session measures it
    again as the uninterrupted one did, reading by reading, to the same parameters."""
    sim, cfg, folder = station
    whole = _run(sim, cfg, folder / "whole", glitch={"glitch_distance_m": GLITCH_M})
    lines = whole.lines
    said = next(n for n, ln in enumerate(lines) if b'"kind":"remeasure"' in ln
                or b'"kind": "remeasure"' in ln)
    records = {p["index"]: p for p in read_trace(whole.session.trace_path).poses}
    for cut, partial in ((said + 1, False), (said + 1, True)):
        out = folder / f"resumed-{cut}-{partial}"
        out.mkdir()
        data = b"".join(lines[:cut]) + (lines[cut][: len(lines[cut]) // 2] if partial else b"")
        (out / "trace.jsonl").write_bytes(data)
        pose = next(p for p in whole.session.plan_poses if p.index == whole.disturbed)
        with sim.control() as ctl:         # the disturbance as in the uninterrupted run
            ctl.call(faults={"glitch_qm": [float(q) for q in pose.qm],
                             "glitch_distance_m": GLITCH_M})
            try:
                with _session(sim, cfg, out) as s:
                    s.run()
            finally:
                ctl.call(clear=True)
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            got = {p["index"]: p for p in read_trace(s.trace_path).poses}
        assert sorted(got) == sorted(records), (cut, partial)
        for i, rec in records.items():
            for key in ("distance", "tilt", "qm", "plan_index", "use"):
                assert got[i][key] == rec[key], (cut, partial, i, key)
            assert got[i].get("remeasure_of") == rec.get("remeasure_of")
        np.testing.assert_allclose(s.outcome.result.x, whole.session.outcome.result.x,
                                   rtol=1e-9, atol=1e-12)


def test_a_failed_gate_without_a_flagged_reading_measures_nothing_again(station, no_report):
    """Too few poses to calibrate (no reading to blame): nothing is measured again and
    the refusal is the calibration's, as before."""
    sim, cfg, folder = station
    with sim.control() as ctl:
        ctl.call(clear=True)
    with _session(sim, cfg, folder / "few", dataclasses.replace(REQUEST, count=6,
                                                                 validation=0)) as s:
        with pytest.raises(CalibrationError, match="poses"):
            s.run()
    assert not [e for e in s.events if e["kind"].startswith("remeasure")]


@pytest.mark.slow
def test_the_drawn_arm_of_issue_40_completes_within_its_std(tmp_path):
    """The session of issue 40 as its user ran it (`app.py run --simulate`, the drawn arm
    of fixtures/truth/agebot-sm-drawn-602.json): refused before for one held-out reading
    4.97 times its predicted std off (the simulator's 4.4 sigma draw at that pose, which
    every visit read again). It completes, and its parameters lie within their reported
    covariance of the truth in the session's frame (d2 on the 13 geometric parameters
    below the chi-square's 99.9 % point; ``distance_off`` is the zero's noise draw)."""
    import subprocess
    import sys

    from scipy.stats import chi2

    from calibration.methods.sm_distance_tilt import reframe_nominal
    from calibration.robots import get_robot
    from drivers.sim.truth import load_truth

    root = Path(__file__).resolve().parents[2]
    truth_file = root / "fixtures" / "truth" / "agebot-sm-drawn-602.json"
    out = tmp_path / "run"
    done = subprocess.run([sys.executable, str(root / "app.py"), "run", "--simulate",
                           "--robot", "agebot-sm", "--method", "sm-distance-tilt", "--truth",
                           str(truth_file), "--out", str(out)], capture_output=True, text=True,
                          cwd=root, timeout=600)
    assert done.returncode == 0, done.stderr
    doc = json.loads((out / "params.json").read_text())
    robot = get_robot("agebot-sm")
    ref = np.array(read_trace(out / "trace.jsonl").reference["qm"])
    truth = robot.as_dict(reframe_nominal(robot, load_truth(truth_file).xi(), ref))
    names = [n for n in doc["covariance"]["names"] if n in truth]
    cov = np.array(doc["covariance"]["matrix"])
    keep = [doc["covariance"]["names"].index(n) for n in names]
    e = np.array([doc["parameters"][n]["value"] - truth[n] for n in names])
    e = np.where([n in robot.angle_params for n in names], (e + np.pi) % (2 * np.pi) - np.pi, e)
    d2 = float(e @ np.linalg.solve(cov[np.ix_(keep, keep)], e))
    again = [ev["plan_index"] for ev in read_trace(out / "trace.jsonl").events
             if ev["kind"] == "remeasure"]
    print(f"d2 {d2:.3g} on {len(names)} parameters; measured again: {again}")
    assert len(names) == 13 and d2 < chi2.ppf(0.999, len(names))
