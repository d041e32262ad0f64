"""Pose design in a session (issue 14): the wrist's rounds are chosen D-optimally given
the poses already measured, the plan says what accuracy it predicts, an accuracy
target adds poses, and the report puts predicted and achieved side by side."""
from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

from station.headless import parse_target
from calibration.errors import ConfigError
from tests.simconfig import quick_config

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
ENV = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1"}


def _start(out, *extra) -> subprocess.Popen:
    """``app.py run --simulate`` of the wrist on the tests' quick simulated station,
    started (each its own simulator on its own ports: independent runs go at once)."""
    cfg = quick_config(out.parent / f"station-{out.name}", "agebot-pm")
    return subprocess.Popen([sys.executable, os.path.join(ROOT, "app.py"), "run", "--simulate",
                             "--robot", "agebot-pm", "--method", "pm-fk", "--config", str(cfg),
                             "--out", str(out), *extra],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=ENV)


def _done(proc: subprocess.Popen) -> subprocess.CompletedProcess:
    out, err = proc.communicate(timeout=600)
    return subprocess.CompletedProcess(proc.args, proc.returncode, out, err)


def _run(out, *extra) -> subprocess.CompletedProcess:
    return _done(_start(out, *extra))


def _plans(out):
    events = [json.loads(ln) for ln in (out / "trace.jsonl").read_text().splitlines()]
    return [e for e in events if e.get("record") == "event" and e.get("kind") == "plan"]


def test_wrist_rounds_are_designed_and_a_target_adds_poses(tmp_path):
    # the runs that do not need the first one's figures go beside it
    started = {name: _start(tmp_path / name, *extra) for name, extra in (
        ("base", ()), ("random", ("--design", "random")), ("far", ("--target-std", "1e-9")))}
    runs = {name: _done(proc) for name, proc in started.items()}
    base = runs["base"]
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
    tight = _run(tmp_path / "tight", "--target-std", repr(goal))
    assert tight.returncode == 0, tight.stderr
    final_t = _plans(tmp_path / "tight")[-1]
    assert len(final_t["poses"]) > n_base
    assert final_t["wrist"]["design"]["predicted_heldout"]["rms"] <= goal

    rnd = runs["random"]
    assert rnd.returncode == 0, rnd.stderr
    assert all("design" not in p["wrist"] for p in _plans(tmp_path / "random"))

    far = runs["far"]
    assert far.returncode == 2 and "even all" in far.stderr and "Traceback" not in far.stderr


@pytest.mark.parametrize("text, want", [("5e-5", ("heldout", 5e-5)), ("k1=1e-6", ("k1", 1e-6)),
                                        (None, None)])
def test_parse_target(text, want):
    assert parse_target(text) == want


@pytest.mark.parametrize("text", ["abc", "-1", "k1=", "=1e-3", "k1=nan", "0"])
def test_parse_target_refuses(text):
    with pytest.raises(ConfigError, match="--target-std"):
        parse_target(text)
