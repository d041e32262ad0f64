"""A wrist session that cannot converge stops before it drives anywhere it should not,
keeps its trace and tells the operator what to do (issue 10)."""
from __future__ import annotations

import json
import subprocess
import sys

import pytest

from calibration.errors import StationError
from drivers.sim.server import SimulatorProcess
from drivers.sim.truth import save_truth
from station.simulation.wrist_sessions import fast_config, wrist_truth
from station.recording.trace import read_trace
from station.planning.wrist_plan import SCOUT_COUNT
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


def test_a_wrist_with_its_sensor_mapped_wrong_stops_after_the_scout(tmp_path, monkeypatch):
    """Past the start's test move (switched off here: a mapping it cannot see), no model
    of the wrist explains the scout's readings: the session stops after the scout poses
    near home, with the trace kept and a one-line message naming what to do."""
    import station.session.plausibility

    from station.planning.request import PlanRequest
    from station.session.session import Session
    from tests.station.test_session import _session_config

    monkeypatch.setattr(station.session.plausibility, "check_wrist", lambda session: None)
    truth = wrist_truth(9400)
    save_truth(truth, tmp_path / "truth.json")
    cfg = fast_config(tmp_path)
    text = cfg.read_text().replace('roll = { raw = "roll", sign = 1',
                                   'roll = { raw = "roll", sign = -1')
    cfg.write_text(text)
    with SimulatorProcess("agebot-pm", truth=str(tmp_path / "truth.json"), config=str(cfg),
                          seed=1) as sim:
        with Session(_session_config(sim, cfg), "pm-fk", tmp_path / "run",
                     request=PlanRequest(count=20, seed=1)) as s:
            with pytest.raises(StationError) as err:
                s.run()
    msg = str(err.value)
    assert "\n" not in msg and "gear ratios" in msg and "data sheets" in msg, msg
    trace = read_trace(tmp_path / "run" / "trace.jsonl")
    assert len(trace.poses) <= SCOUT_COUNT                     # nothing beyond the scout
    assert [e["kind"] for e in trace.events][-1] == "stop"
    assert not (tmp_path / "run" / "params.json").exists()
