"""One session per output folder (station.recording.lock): the second is refused with one line
naming the first one's process, and a lock left by a crashed run is taken over."""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time

import pytest

from drivers.config import load_station_config
from drivers.sim.server import SimulatorProcess
from station.recording.lock import FolderLock, FolderLocked, holder
from station.session.session import Session
from station.recording.trace import read_trace
from tests.station.test_session import FIX, ROOT, _poses_in, fast_config


def test_a_second_lock_on_a_folder_is_refused_naming_the_first(tmp_path):
    with FolderLock(tmp_path / "run") as first:
        with pytest.raises(FolderLocked, match=rf"pid {os.getpid()} on "):
            FolderLock(tmp_path / "run").acquire()
        assert holder(tmp_path / "run")["pid"] == os.getpid()
        assert first.stale is None
    assert holder(tmp_path / "run") is None
    FolderLock(tmp_path / "run").acquire().release()        # free again


def test_a_session_holds_its_folder_until_closed(tmp_path):
    config = load_station_config(FIX / "stations" / "sim-sm.toml")
    with Session(config, "sm-distance-tilt", tmp_path / "run"):
        with pytest.raises(FolderLocked, match="another session is using this folder"):
            Session(config, "sm-distance-tilt", tmp_path / "run")
    with Session(config, "sm-distance-tilt", tmp_path / "run"):
        pass


def test_a_stale_lock_of_a_killed_run_is_taken_over(tmp_path):
    folder = tmp_path / "run"
    code = ("import sys, time; from station.recording.lock import FolderLock; "
            f"FolderLock({str(folder)!r}).acquire(); print('locked', flush=True); time.sleep(60)")
    p = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True)
    try:
        assert p.stdout.readline().strip() == "locked"
        with pytest.raises(FolderLocked, match=rf"pid {p.pid} "):
            FolderLock(folder).acquire()
    finally:
        os.kill(p.pid, signal.SIGKILL)
        p.wait()
        p.stdout.close()
    assert json.loads((folder / "session.lock").read_text())["pid"] == p.pid   # left behind
    config = load_station_config(FIX / "stations" / "sim-sm.toml")
    with Session(config, "sm-distance-tilt", folder) as s:
        assert holder(folder)["pid"] == os.getpid()
    taken = [e["message"] for e in s.events if e["kind"] == "info"]
    assert any(f"pid {p.pid}" in m and "no longer running" in m for m in taken), taken


@pytest.mark.heavy
def test_two_headless_sessions_on_one_folder(tmp_path):
    """The second `app.py run` on a folder in use exits with one line naming the first
    one's process; the first finishes with a readable trace."""
    cfg = fast_config(tmp_path, "agebot-sm")
    with SimulatorProcess("agebot-sm", config=str(cfg), seed=5) as sim:
        ep = tmp_path / "endpoints.json"
        ep.write_text(json.dumps(sim.endpoints))
        cmd = [sys.executable, str(ROOT / "app.py"), "run", "--robot", "agebot-sm",
               "--method", "sm-distance-tilt", "--config", str(cfg), "--endpoints", str(ep),
               "--count", "8", "--seed", "5", "--out", str(tmp_path / "run"), "--one-shot",
               "--accept-poor-fit"]   # 8 poses fail the fit-quality gate; the lock is tested
        first = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
        try:
            deadline = time.monotonic() + 60
            while _poses_in(tmp_path / "run" / "trace.jsonl") < 2:
                assert first.poll() is None, first.stderr.read().decode()
                assert time.monotonic() < deadline, "the first session recorded no poses"
                time.sleep(0.05)
            second = subprocess.run(cmd, capture_output=True, text=True, timeout=60)
            assert second.returncode != 0
            err = second.stderr.strip().splitlines()
            assert len(err) == 1 and f"pid {first.pid} on " in err[0], second.stderr
            assert "Traceback" not in second.stderr
            assert first.wait(timeout=120) == 0, first.stderr.read().decode()
        finally:
            if first.poll() is None:
                first.kill()
            first.stderr.close()
    trace = read_trace(tmp_path / "run" / "trace.jsonl")
    idx = [p["plan_index"] for p in trace.current_poses]
    assert len(idx) == len(set(idx)) == 8 + 3 and (tmp_path / "run" / "params.json").exists()
