"""A wrist session that cannot converge stops before it drives anywhere it should not,
keeps its trace and tells the operator what to do (issue 10)."""
from __future__ import annotations

import json
import subprocess
import sys

from drivers.sim.server import SimulatorProcess
from drivers.sim.truth import save_truth
from station.sim_wrist import fast_config, wrist_truth
from station.trace import read_trace
from tests.station.test_session import ROOT


def _run_mapped_wrong(tmp_path, axis: str):
    """app.py run on a wrist whose inclinometer ``axis`` is mapped with the wrong sign."""
    truth = wrist_truth(9400)
    save_truth(truth, tmp_path / "truth.json")
    cfg = fast_config(tmp_path)
    text = cfg.read_text().replace(f'{axis} = {{ raw = "{axis}", sign = 1',
                                   f'{axis} = {{ raw = "{axis}", sign = -1')
    assert text != cfg.read_text()
    cfg.write_text(text)
    with SimulatorProcess("agebot-pm", truth=str(tmp_path / "truth.json"), config=str(cfg),
                          seed=1) as sim:
        ep = tmp_path / "endpoints.json"
        ep.write_text(json.dumps(sim.endpoints))
        return subprocess.run(
            [sys.executable, str(ROOT / "app.py"), "run", "--robot", "agebot-pm", "--method",
             "pm-fk", "--config", str(cfg), "--endpoints", str(ep), "--count", "20",
             "--seed", "1", "--out", str(tmp_path / "run")],
            capture_output=True, text=True, timeout=240)


def test_a_wrist_with_its_roll_mapped_wrong_is_refused_before_the_scout(tmp_path):
    """The roll mapped with the wrong sign: the test move at the start (station/
    plausibility.py) turns the sensor's roll the other way than the model's, so the
    session stops before planning, with one line naming the axis; nothing recorded."""
    done = _run_mapped_wrong(tmp_path, "roll")
    assert done.returncode != 0
    err = done.stderr.strip()
    assert "Traceback" not in err and len(err.splitlines()) == 1, err
    assert "the opposite sign: check inclinometer.axes.roll" in err, err
    assert not (tmp_path / "run" / "trace.jsonl").exists()
    assert not (tmp_path / "run" / "params.json").exists()


def test_a_wrist_with_its_yaw_mapped_wrong_stops(tmp_path):
    """The yaw (which the start's test move does not check) mapped with the wrong sign:
    no model of the wrist explains the readings, so the session stops with the trace
    kept and a one-line message naming what to do."""
    done = _run_mapped_wrong(tmp_path, "yaw")
    assert done.returncode != 0
    err = done.stderr.strip()
    assert "Traceback" not in err and "gear ratios" in err and "data sheets" in err, err
    trace = read_trace(tmp_path / "run" / "trace.jsonl")
    assert [e["kind"] for e in trace.events][-1] == "stop"
    assert not (tmp_path / "run" / "params.json").exists()


def test_a_wrist_session_aborted_mid_growth_resumes_its_rounds(tmp_path):
    """Aborted in a growing round, a new Session on the folder takes the model, round
    and home of the trace's plan events and grows on to the +-20 deg round."""
    from drivers.config import load_station_config
    from drivers.endpoints import with_endpoints
    from station.planner import PlanRequest
    from station.session import Session, SessionAborted
    from station.sim_wrist import ik_error

    truth = wrist_truth(9401)
    save_truth(truth, tmp_path / "truth.json")
    cfg = fast_config(tmp_path)
    req = dict(count=20, validation=4, seed=2)
    with SimulatorProcess("agebot-pm", truth=str(tmp_path / "truth.json"), config=str(cfg),
                          seed=2) as sim:
        config = with_endpoints(load_station_config(cfg), sim.endpoints, source="simulator")
        first = None

        def stop_in_round_one(kind, payload):
            if kind == "progress" and payload.readings and payload.pose.round == 1:
                first.abort()

        first = Session(config, "pm-fk", tmp_path / "run", request=PlanRequest(**req),
                        observer=stop_in_round_one)
        try:
            first.run()
            raise AssertionError("not aborted")
        except SessionAborted:
            pass
        finally:
            first.close()
        with Session(config, "pm-fk", tmp_path / "run", request=PlanRequest(**req)) as again:
            assert again.resumed and again.wrist.rounds == 2 and again.wrist.xi is not None
            again.run()
    trace = read_trace(tmp_path / "run" / "trace.jsonl")
    idx = [p["plan_index"] for p in trace.poses]
    assert len(idx) == len(set(idx))                                 # nothing measured twice
    plans = [e["wrist"] for e in trace.events if e["kind"] == "plan"]
    assert [p["round"] for p in plans] == list(range(len(plans))) and plans[-1]["final"]
    assert len(trace.fit_poses) >= 20 and len(trace.validation_poses) == 4
    assert ik_error(again.outcome.result.x, truth.xi()) < 1.0
