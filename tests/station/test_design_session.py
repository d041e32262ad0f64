"""Pose design in a session (issue 14): the wrist's rounds are chosen D-optimally given
the poses already measured, the plan says what accuracy it predicts, an accuracy
target adds poses, and the report puts predicted and achieved side by side."""
from __future__ import annotations

import json
import logging
import os
import subprocess
import sys

import pytest

import app
from station.headless import parse_target
from calibration.errors import ConfigError
from tests.simconfig import quick_config

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
ENV = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1"}


def _args(out, *extra) -> list[str]:
    """``app.py run --simulate`` of the wrist on the tests' quick simulated station (each
    run its own simulator on its own ports and its own config beside ``out``)."""
    cfg = quick_config(out.parent / f"station-{out.name}", "agebot-pm")
    return ["run", "--simulate", "--robot", "agebot-pm", "--method", "pm-fk", "--config",
            str(cfg), "--out", str(out), *extra]


def _start(out, *extra) -> subprocess.Popen:
    """:func:`_args` as a command, started (it runs beside the test)."""
    return subprocess.Popen([sys.executable, os.path.join(ROOT, "app.py"), *_args(out, *extra)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=ENV)


def _done(proc: subprocess.Popen) -> subprocess.CompletedProcess:
    out, err = proc.communicate(timeout=600)
    return subprocess.CompletedProcess(proc.args, proc.returncode, out, err)


def _here(capsys, caplog, out, *extra) -> subprocess.CompletedProcess:
    """:func:`_args` run in this process (app.main), its output captured: for the runs
    whose report is not read (the ``no_report`` fixture), without a second interpreter
    and its imports. A traceback the command would print goes to pytest's log capture
    here, not to the output: one logged with an exception is put in ``stderr``."""
    args = _args(out, *extra)
    capsys.readouterr()
    caplog.clear()
    rc = app.main(args)
    got = capsys.readouterr()
    logged = "".join(f"Traceback (logged): {r.getMessage()}\n" for r in caplog.records
                     if r.exc_info)
    return subprocess.CompletedProcess(["app.py", *args], rc, got.out, got.err + logged)


def _plans(out):
    events = [json.loads(ln) for ln in (out / "trace.jsonl").read_text().splitlines()]
    return [e for e in events if e.get("record") == "event" and e.get("kind") == "plan"]


@pytest.mark.heavy
# a thread of an in-process run that dies fails the test, as its traceback would in a command's stderr
@pytest.mark.filterwarnings("error::pytest.PytestUnhandledThreadExceptionWarning")
def test_wrist_rounds_are_designed_and_a_target_adds_poses(tmp_path, capsys, caplog, no_report,
                                                           monkeypatch):
    # the first run, whose report is read, as a command beside the test; the runs that
    # do not need its figures meanwhile in this process, without their reports (app.main
    # quiets pymodbus's logger: restored after the test)
    pymodbus = logging.getLogger("pymodbus")
    monkeypatch.setattr(pymodbus, "level", pymodbus.level)
    proc = _start(tmp_path / "base")
    rnd = _here(capsys, caplog, tmp_path / "random", "--design", "random")
    far = _here(capsys, caplog, tmp_path / "far", "--target-std", "1e-9")
    base = _done(proc)
    assert base.returncode == 0, base.stderr
    plans = _plans(tmp_path / "base")
    final = plans[-1]["wrist"]
    assert final["final"] and final["design"]["design"] == "optimal"
    pred = final["design"]["predicted_heldout"]
    assert pred["what"] == "orientation" and pred["unit"] == "rad" and pred["rms"] > 0
    assert "D-optimal poses" in base.stdout and "predicted held-out orientation error" in base.stdout
    report = (tmp_path / "base" / "report.html").read_text()
    assert "Predicted and achieved" in report
    n_base = len(plans[-1]["poses"])

    goal = pred["rms"] / 2
    tight = _here(capsys, caplog, tmp_path / "tight", "--target-std", repr(goal))
    assert tight.returncode == 0 and "Traceback" not in tight.stderr, tight.stderr
    final_t = _plans(tmp_path / "tight")[-1]
    assert len(final_t["poses"]) > n_base
    assert final_t["wrist"]["design"]["predicted_heldout"]["rms"] <= goal

    assert rnd.returncode == 0 and "Traceback" not in rnd.stderr, rnd.stderr
    assert all("design" not in p["wrist"] for p in _plans(tmp_path / "random"))

    assert far.returncode == 2 and "even all" in far.stderr and "Traceback" not in far.stderr


@pytest.mark.parametrize("text, want", [("5e-5", ("heldout", 5e-5)), ("k1=1e-6", ("k1", 1e-6)),
                                        (None, None)])
def test_parse_target(text, want):
    assert parse_target(text) == want


@pytest.mark.parametrize("text", ["abc", "-1", "k1=", "=1e-3", "k1=nan", "0"])
def test_parse_target_refuses(text):
    with pytest.raises(ConfigError, match="--target-std"):
        parse_target(text)
