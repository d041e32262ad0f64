"""Session-side mistakes and accidents are one line, and leave a resumable trace:
a full disk during a session, a station config saved as UTF-16 (the missing
[drawwire] case is in test_plausibility.py, a lost device in test_device_loss.py)."""
from __future__ import annotations

import subprocess
import sys

import pytest

from calibration.errors import ConfigError, StationError
from drivers.config import load_station_config
from drivers.sim.server import SimulatorProcess
from station.planning.request import PlanRequest
from station.session.session import Session
from station.recording.trace import read_trace
from tests.station.test_session import FIX, ROOT, _session_config, fast_config


def test_a_full_disk_during_a_session_is_one_line_and_the_trace_resumes(tmp_path):
    """The trace's file handle swapped for one on /dev/full after 3 poses: the kernel
    answers ENOSPC at the next append; the session stops with one line, the trace on
    disk is intact, and once there is space again the session resumes and finishes."""
    cfg = fast_config(tmp_path, "agebot-sm")
    out = tmp_path / "run"
    request = PlanRequest(count=8, validation=2, seed=2)
    with SimulatorProcess("agebot-sm", config=str(cfg), seed=3) as sim:
        config = _session_config(sim, cfg)
        full = []

        def observer(kind, payload):
            if kind == "progress" and payload.readings and payload.done == 3 and not full:
                w = s._writer
                w._fh.close()
                w._fh = open("/dev/full", "ab")
                full.append(True)

        with Session(config, "sm-distance-tilt", out, request=request, observer=observer) as s:
            with pytest.raises(StationError) as err:
                s.run()
        msg = str(err.value)
        assert "No space left on device" in msg and "\n" not in msg, msg
        assert msg.startswith(str(out / "trace.jsonl")) and "run the session again" in msg
        assert len(read_trace(out / "trace.jsonl").poses) == 3
        # 8 poses: the quality gate refuses the fit, rightly; this test is about the disk
        with Session(config, "sm-distance-tilt", out, request=request,
                     accept_poor_fit=True) as again:
            again.run()
    trace = read_trace(out / "trace.jsonl")
    assert sorted(p["plan_index"] for p in trace.current_poses) == list(range(10))


@pytest.mark.parametrize("encoding", ["utf-16", "utf-16-le"])
def test_a_utf16_station_config_is_one_line(tmp_path, encoding):
    path = tmp_path / "station.toml"
    path.write_bytes((FIX / "stations" / "sim-sm.toml").read_text().encode(encoding))
    with pytest.raises(ConfigError, match=r"station.toml: UTF-16 text \(or not text at all\): save the file as UTF-8"):
        load_station_config(path)
    r = subprocess.run([sys.executable, str(ROOT / "app.py"), "run", "--robot", "agebot-sm",
                        "--method", "sm-distance-tilt", "--config", str(path), "--out",
                        str(tmp_path / "run")], capture_output=True, text=True, timeout=60)
    err = r.stderr.strip().splitlines()
    assert r.returncode != 0 and len(err) == 1 and "UTF-16" in err[0], r.stderr
    assert not (tmp_path / "run").exists()


def test_a_utf8_config_with_a_bom_is_read(tmp_path):
    path = tmp_path / "station.toml"
    path.write_bytes(b"\xef\xbb\xbf" + (FIX / "stations" / "sim-sm.toml").read_bytes())
    assert load_station_config(path).robot == "agebot-sm"
