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
from station.wrist_plan import SCOUT_COUNT
from tests.station.test_session import ROOT


def test_a_wrist_with_its_sensor_mapped_wrong_stops_after_the_scout(tmp_path):
    """The inclinometer's roll mapped with the wrong sign: no model of the wrist explains
    the scout's readings, so the session stops after the scout poses near home, with
    the trace kept and a one-line message naming what to do."""
    truth = wrist_truth(9400)
    save_truth(truth, tmp_path / "truth.json")
    cfg = fast_config(tmp_path)
    text = cfg.read_text().replace('roll = { raw = "roll", sign = 1',
                                   'roll = { raw = "roll", sign = -1')
    assert text != cfg.read_text()
    cfg.write_text(text)
    with SimulatorProcess("agebot-pm", truth=str(tmp_path / "truth.json"), config=str(cfg),
                          seed=1) as sim:
        ep = tmp_path / "endpoints.json"
        ep.write_text(json.dumps(sim.endpoints))
        done = subprocess.run(
            [sys.executable, str(ROOT / "app.py"), "run", "--robot", "agebot-pm", "--method",
             "pm-fk", "--config", str(cfg), "--endpoints", str(ep), "--count", "20",
             "--seed", "1", "--out", str(tmp_path / "run")],
            capture_output=True, text=True, timeout=240)
    assert done.returncode != 0
    err = done.stderr.strip()
    assert "Traceback" not in err and "gear ratios" in err and "data sheets" in err, err
    trace = read_trace(tmp_path / "run" / "trace.jsonl")
    assert len(trace.poses) <= SCOUT_COUNT                     # nothing beyond the scout
    assert [e["kind"] for e in trace.events][-1] == "stop"
    assert not (tmp_path / "run" / "params.json").exists()
