"""The inclinometer's range and the reference's test moves (issue 23, finding 4): a
range per inclinometer channel in the station config, honoured by a robot file's
planning and its recording; a wrong-sign start value refused at the reference by the
joints' direction test (AGEBOT's sm-distance, a robot file's), before any pose."""
from __future__ import annotations

import math

import numpy as np
import pytest

from calibration import simulate
from calibration.errors import ConfigError
from drivers.config import load_station_config
from drivers.endpoints import with_endpoints
from drivers.sim.server import SimulatorProcess
from station.planning.request import PlanRequest
from station.session.session import Session
from station.recording.trace import read_trace
from tests.station.test_cli import app
from tests.station.test_serial_session import HAYATI, _fast_config, _truth_file
from tests.simconfig import quick_config

RANGE = math.radians(60.0)


def _ranged(path, r=RANGE):
    text = path.read_text()
    for axis in ("roll", "pitch"):
        text = text.replace(f'[inclinometer.axes.{axis}]\nraw = "{axis}"',
                            f'[inclinometer.axes.{axis}]\nraw = "{axis}"\nrange_rad = {r}')
    assert text.count("range_rad") == 2
    path.write_text(text)
    return path


def test_range_is_read_from_the_config(tmp_path):
    cfg = load_station_config(_ranged(_fast_config(tmp_path, HAYATI)))
    assert cfg.inclinometer.axes["roll"].range_rad == pytest.approx(RANGE)
    bad = _ranged(_fast_config(tmp_path, HAYATI), r=-1.0)
    with pytest.raises(ConfigError, match=r"inclinometer\.axes\.roll\.range_rad"):
        load_station_config(bad)


def test_robot_file_session_plans_only_readable_orientations(tmp_path):
    """Without a range the UR5-like arm's plan has most tool orientations beyond
    +-60 deg of the inclinometer; with range_rad = 60 deg none is planned there, the
    reference included, and the test move at the reference reads roll and pitch."""
    cfg_path = _ranged(_fast_config(tmp_path, HAYATI, samples=2))
    truth = _truth_file(tmp_path, HAYATI, 3)
    with SimulatorProcess(HAYATI, truth=str(truth), config=str(cfg_path)) as sim:
        cfg = with_endpoints(load_station_config(cfg_path), sim.endpoints, source="sim")
        with Session(cfg, "sm-distance-tilt", tmp_path / "s",
                     request=PlanRequest(count=30), station={"simulator": {}}) as s:
            s.connect()
            qm, _, _ = s.reference_target()
            s.capture_reference(qm)
            said = [e["message"] for e in s.events if e["kind"] == "info"]
            assert any("plausible at the reference" in m and "roll" in m for m in said), said
            poses = s.plan()
            q = np.array([p.qm for p in poses] + [list(s.reference_qm)])
            tilt = simulate.measure("sm-distance-tilt", s.robot, s.nominal, q,
                                    reference_qm=s.reference_qm)["tilt"]
            assert np.all(np.abs(tilt) <= RANGE), np.degrees(np.abs(tilt).max())
            assert len(poses) >= 30


def test_a_reading_beyond_the_range_is_not_recorded(tmp_path):
    from station.session.session import Session as S

    cfg = load_station_config(_ranged(_fast_config(tmp_path, HAYATI)))
    from station.session import plausibility

    said = plausibility.range_problems(cfg, {"roll": math.radians(75), "pitch": 0.1}, "here")
    assert len(said) == 1 and "roll reads +75.0 deg here" in said[0]
    assert "inclinometer.axes.roll.range_rad" in said[0]
    assert "roll" in S.inclinometer_channels.fget(type("X", (), {
        "serial": True, "method": "sm-distance-tilt"})())


def test_agebot_wrong_sign_start_value_refused_at_the_reference(tmp_path):
    """--nominal k2=-0.01 (the truth's is +0.0091): before, 162 poses were measured and
    the calibration did not converge; now the reference's direction test says it."""
    station = quick_config(tmp_path / "station", "agebot-sm")
    out = tmp_path / "s"
    r = app("run", "--simulate", "--robot", "agebot-sm", "--method", "sm-distance",
            "--config", str(station), "--nominal", "k2=-0.01", "--out", str(out))
    assert r.returncode == 2, r.stdout[-2000:]
    line = r.stderr.strip().splitlines()[-1]
    assert "do not turn as the start values say" in line and "k2" in line
    assert "nothing was recorded" in line
    trace = out / "trace.jsonl"
    assert not trace.exists() or not read_trace(trace).poses


def test_robot_file_wrong_sign_start_value_refused_at_the_reference(tmp_path):
    cfg = _fast_config(tmp_path, HAYATI, samples=2)
    truth = _truth_file(tmp_path, HAYATI, 3)
    out = tmp_path / "s"
    r = app("run", "--simulate", "--robot", str(HAYATI), "--method", "sm-distance", "--truth",
            str(truth), "--config", str(cfg), "--nominal", "k3=-1", "--out", str(out))
    assert r.returncode == 2, r.stdout[-2000:]
    line = r.stderr.strip().splitlines()[-1]
    assert "do not turn as the start values say" in line and "k3" in line
    trace = out / "trace.jsonl"
    assert not trace.exists() or not read_trace(trace).poses
