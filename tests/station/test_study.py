"""``app.py study``: Monte Carlo over drawn robots on Dask, the same figures on a
local cluster and on a scheduler started by hand with two workers."""
from __future__ import annotations

import json
import os
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
ENV = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1",
       "PYTHONPATH": str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", "")}


def _app(*args, timeout=300):
    return subprocess.run([sys.executable, str(ROOT / "app.py"), *args], capture_output=True,
                          text=True, timeout=timeout, env=ENV, cwd=ROOT)


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture
def scheduler():
    """``dask scheduler`` and two ``dask worker`` processes on loopback."""
    port = _free_port()
    addr = f"tcp://127.0.0.1:{port}"
    dask = [sys.executable, "-m", "distributed.cli.dask_scheduler"]
    procs = [subprocess.Popen(dask + ["--host", "127.0.0.1", "--port", str(port),
                                      "--no-dashboard"], env=ENV, cwd=ROOT,
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)]
    try:
        deadline = time.monotonic() + 60
        while True:
            try:
                socket.create_connection(("127.0.0.1", port), timeout=1).close()
                break
            except OSError:
                if time.monotonic() > deadline:
                    raise RuntimeError("the dask scheduler did not start")
                time.sleep(0.2)
        for _ in range(2):
            procs.append(subprocess.Popen(
                [sys.executable, "-m", "distributed.cli.dask_worker", addr, "--nthreads", "1",
                 "--no-dashboard"], env=ENV, cwd=ROOT, stdout=subprocess.DEVNULL,
                stderr=subprocess.DEVNULL))
        yield addr
    finally:
        # the workers first, while their scheduler still answers their goodbye (with it
        # gone first they wait out its timeouts: 8 s of teardown), then the scheduler
        for group in (procs[1:], procs[:1]):
            for p in group:
                p.terminate()
            for p in group:
                try:
                    p.wait(timeout=20)
                except subprocess.TimeoutExpired:
                    p.kill()


def _table(stdout: str) -> list[str]:
    return [ln for ln in stdout.splitlines() if ln.startswith(("optimal", "random"))]


@pytest.mark.heavy
def test_study_same_figures_on_a_hand_started_scheduler(tmp_path, scheduler):
    args = ["study", "--method", "sm-distance", "--robots", "3", "--seed", "7"]
    local = _app(*args, "--workers", "1", "--out", str(tmp_path / "local"))
    assert local.returncode == 0, local.stderr
    remote = _app(*args, "--scheduler", scheduler, "--out", str(tmp_path / "remote"))
    assert remote.returncode == 0, remote.stderr
    rows = _table(local.stdout)
    assert [r.split()[0] for r in rows] == ["optimal", "random"]
    assert rows == _table(remote.stdout)
    a = json.loads((tmp_path / "local" / "summary.json").read_text())
    b = json.loads((tmp_path / "remote" / "summary.json").read_text())
    assert a["summary"] == b["summary"]
    recs = [json.loads(ln) for ln in (tmp_path / "local" / "study.jsonl").read_text().splitlines()]
    assert sorted((r["index"], r["design"]) for r in recs) == [
        (i, d) for i in range(3) for d in ("optimal", "random")]
    ok = [r for r in recs if r["ok"]]
    assert ok and all(len(r["z"]) == 9 for r in ok)
    # the figures printed are the records' figures
    s = a["summary"]["optimal"]
    assert f"{s['success_rate']:.1%}" in rows[0] and f"{s['rms_z']:.3f}" in rows[0]
    assert "calibrations" in local.stderr  # the progress bar


def test_study_bad_options_one_line(tmp_path):
    for args, msg in ((["--method", "sm-nope"], "unknown method"),
                      (["--method", "sm-distance", "--design", "best"], "--design"),
                      (["--method", "sm-distance", "--gear", "1.5"], "--gear"),
                      (["--method", "sm-distance", "--robot", "agebot-pm"], "is for agebot-sm"),
                      (["--method", "sm-markers"], "not one of AGEBOT's")):
        r = _app("study", *args, "--robots", "2", "--out", str(tmp_path / "x"))
        assert r.returncode == 2 and msg in r.stderr and "Traceback" not in r.stderr, r.stderr
        assert len(r.stderr.strip().splitlines()) == 1
    r = _app("study", "--method", "sm-distance", "--robots", "1", "--scheduler",
             f"tcp://127.0.0.1:{_free_port()}", "--out", str(tmp_path / "y"))
    assert r.returncode == 2 and "cannot reach the Dask scheduler" in r.stderr, r.stderr


@pytest.mark.slow       # four calibrations of a URDF arm and two of a robot file: CI runs it
def test_study_of_a_urdf_robot_and_a_robot_file(tmp_path):
    """A study takes a robot file's and a URDF robot's arm: drawn around their nominal,
    calibrated, the reported std honest (|z| RMS near 1) and the held-out error small."""
    urdf = str(ROOT / "fixtures" / "robots" / "m10ia-like.urdf")
    r = _app("study", "--method", "sm-markers", "--robot", urdf, "--base-link", "base_link",
             "--tip-link", "tool0", "--robots", "2", "--workers", "1", "--out",
             str(tmp_path / "u"))
    assert r.returncode == 0, r.stderr
    summary = json.loads((tmp_path / "u" / "summary.json").read_text())["summary"]
    for design in ("optimal", "random"):
        s = summary[design]
        assert s["success_rate"] == 1.0 and 0.5 < s["rms_z"] < 2.0, s
        assert s["heldout_rms"]["marker"]["p95"] < 2e-4          # m: 0.1 mm readings
    toml = str(ROOT / "fixtures" / "robots" / "ur5-like-hayati.toml")
    r = _app("study", "--method", "sm-distance", "--robot", toml, "--robots", "2",
             "--workers", "1", "--out", str(tmp_path / "f"))
    assert r.returncode == 0, r.stderr
    assert "drawn at random" in r.stdout
    s = json.loads((tmp_path / "f" / "summary.json").read_text())["summary"]["random"]
    assert s["success_rate"] == 1.0 and 0.5 < s["rms_z"] < 2.0, s
    r = _app("study", "--method", "sm-distance", "--robot", urdf, "--base-link", "base_link",
             "--tip-link", "tool0", "--robots", "2", "--out", str(tmp_path / "x"))
    assert r.returncode == 2 and "simulates sm-markers" in r.stderr, r.stderr
