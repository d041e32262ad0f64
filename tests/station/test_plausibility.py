"""A mis-configured station is caught before any pose is recorded: at the
reference (a swapped Modbus word order, a flipped inclinometer sign) and before any
motion (a missing [drawwire] with sm-distance-tilt)."""
from __future__ import annotations

import subprocess
import sys

import pytest

from calibration.errors import ConfigError
from drivers.config import load_station_config
from drivers.sim.server import SimulatorProcess
from station.planning.request import PlanRequest
from station.session.session import Session
from tests.station.test_session import FIX, ROOT, _session_config, fast_config


def _variant(tmp_path, cfg, old: str, new: str, name: str):
    text = cfg.read_text()
    assert old in text
    path = tmp_path / name
    path.write_text(text.replace(old, new))
    return path


@pytest.mark.parametrize("old, new, expected", [
    ('word_order = "high-first"', 'word_order = "low-first"', "check drawwire.word_order"),
    ('sign = 1,', 'sign = -1,', "the opposite sign: check inclinometer.axes.tilt"),
    ("metres_per_count = 1e-6", "metres_per_count = 1e-5", "drawwire.metres_per_count"),
])
def test_a_misconfigured_device_is_caught_at_the_reference(tmp_path, old, new, expected):
    cfg = fast_config(tmp_path, "agebot-sm")
    wrong = _variant(tmp_path, cfg, old, new, "wrong.toml")
    out = tmp_path / "run"
    with SimulatorProcess("agebot-sm", config=str(cfg), seed=4) as sim:
        with Session(_session_config(sim, wrong), "sm-distance-tilt", out,
                     request=PlanRequest(count=8, validation=2, seed=1)) as s:
            with pytest.raises(ConfigError) as err:
                s.run()
    msg = str(err.value)
    print(msg)
    assert expected in msg and "\n" not in msg and "nothing was recorded" in msg
    assert s.reference_qm is None and not s.measured
    assert not (out / "trace.jsonl").exists()


def test_a_right_config_passes_and_says_so(tmp_path):
    cfg = fast_config(tmp_path, "agebot-sm")
    with SimulatorProcess("agebot-sm", config=str(cfg), seed=4) as sim:
        with Session(_session_config(sim, cfg), "sm-distance-tilt", tmp_path / "run") as s:
            s.connect()
            s.move_to(s.reference_target()[0])
            s.capture_reference()
    said = [e["message"] for e in s.events if e["kind"] == "info"]
    assert any(m.startswith("plausible at the reference") for m in said), said


def test_a_missing_drawwire_section_is_refused_before_any_motion(tmp_path):
    text = (FIX / "stations" / "sim-sm.toml").read_text()
    cut = text[:text.index("[drawwire]")] + text[text.index("[snapshot]"):]
    path = tmp_path / "no-drawwire.toml"
    path.write_text(cut)
    with pytest.raises(ConfigError, match=r"no-drawwire.toml: drawwire: sm-distance-tilt "
                                          r"measures distances, and the station config has "
                                          r"no \[drawwire\] section"):
        Session(load_station_config(path), "sm-distance-tilt", tmp_path / "run")
    # the command line: one line, before the simulator moved anything
    r = subprocess.run([sys.executable, str(ROOT / "app.py"), "run", "--simulate", "--robot",
                        "agebot-sm", "--method", "sm-distance-tilt", "--config", str(path),
                        "--out", str(tmp_path / "cli")], capture_output=True, text=True,
                       timeout=120)
    assert r.returncode != 0 and "Traceback" not in r.stderr
    err = r.stderr.strip().splitlines()
    assert len(err) == 1 and "no [drawwire] section" in err[0], r.stderr
    assert not (tmp_path / "cli" / "trace.jsonl").exists()


@pytest.mark.parametrize("old, new, expected", [
    ('roll = { raw = "roll", sign = 1,', 'roll = { raw = "roll", sign = -1,',
     "changed the inclinometer's roll by"),
    ('roll = { raw = "roll",', 'roll = { raw = "pitch",', "check inclinometer.axes."),
])
def test_a_misconfigured_wrist_inclinometer_is_caught_before_planning(tmp_path, old, new,
                                                                      expected):
    cfg = fast_config(tmp_path, "agebot-pm")
    wrong = _variant(tmp_path, cfg, old, new, "wrong.toml")
    with SimulatorProcess("agebot-pm", config=str(cfg), seed=4) as sim:
        with Session(_session_config(sim, wrong), "pm-fk", tmp_path / "run") as s:
            with pytest.raises(ConfigError) as err:
                s.run()
        with Session(_session_config(sim, cfg), "pm-fk", tmp_path / "right") as right:
            right.connect()
            right.plan()
    msg = str(err.value)
    print(msg)
    assert expected in msg and "\n" not in msg and not s.measured and not s.plan_poses
    said = [e["message"] for e in right.events if e["kind"] == "info"]
    assert any(m.startswith("plausible at the wrist's start") for m in said), said
