"""The README's first command as an operator meets it: reproducible by default (the
simulator seeded, the seed printed and recorded), readings with units, a finished
folder run again appends nothing, and an interrupted run says how to resume."""
import json
import os
import signal
import subprocess
import sys
import time

import pytest

from tests.simconfig import quick_config

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
# 8 poses are too few for a fit that passes the fit-quality gate; this test is about
# reproducibility and resuming, so the poor fit is accepted
COMMAND = ["run", "--simulate", "--robot", "agebot-sm", "--method", "sm-distance-tilt",
           "--count", "8", "--accept-poor-fit"]


def quick(folder):
    """``--config`` of the tests' quick simulated station (tests/simconfig.py)."""
    return ["--config", str(quick_config(folder / "station", "agebot-sm"))]


def start(out, *extra) -> subprocess.Popen:
    """The command into ``out``, started (its own simulator; its own station config
    beside ``out``: independent runs go at once)."""
    return subprocess.Popen([sys.executable, os.path.join(ROOT, "app.py"), *COMMAND,
                             *quick(out.parent / f"config-{out.name}"), "--out", str(out),
                             *extra],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT)


def done(proc: subprocess.Popen, timeout=240) -> subprocess.CompletedProcess:
    out, err = proc.communicate(timeout=timeout)
    return subprocess.CompletedProcess(proc.args, proc.returncode, out, err)


def run(out, *extra, timeout=240):
    return done(start(out, *extra), timeout)


def records(path):
    return [json.loads(line) for line in open(path, encoding="utf-8")]


def values(folder):
    doc = json.loads((folder / "params.json").read_text())
    return {k: p["value"] for k, p in doc["parameters"].items()}


@pytest.mark.heavy
def test_default_runs_are_reproducible_and_a_finished_folder_stays(tmp_path):
    a, b, c = tmp_path / "a", tmp_path / "b", tmp_path / "c"
    # three runs at once (reproducible however the machine's load times them); c with
    # another simulator seed
    ra, rb, rc = [done(p) for p in (start(a), start(b), start(c, "--sim-seed", "5"))]
    assert ra.returncode == 0, ra.stderr
    assert rb.returncode == 0, rb.stderr
    assert values(a) == values(b)          # bit-identical, not approximately
    ta, tb = records(a / "trace.jsonl"), records(b / "trace.jsonl")
    poses = [[{k: v for k, v in r.items() if k != "t"} for r in t if r["record"] == "pose"]
             for t in (ta, tb)]
    assert poses[0] == poses[1]
    fit = [r for r in poses[0] if r["use"] == "fit"]
    # the default plans the arm in rounds: a 6-pose scout and 6 in 30 % of the box on
    # top of the 8 asked for, in the whole box (station/planning/arm_rounds.py); reproducible too
    assert len(fit) == 8 + 6 + 6 and len(poses[0]) > len(fit)     # and the held-out ones
    plans = [r for r in ta if r["record"] == "event" and r["kind"] == "plan"]
    assert sorted({p["round"] for ev in plans for p in ev["poses"]}) == [0, 1, 2]
    # where the envelope stops the arm depends on when the watch reads it: the
    # default run plans no move it stops. Its 6-pose refit does not converge (run to 50
    # iterations it once made L3 a third of the nominal's, and planned with that the
    # next pose read 0.27 m where it predicted 0.05 m): a refit that does not explain
    # the readings, or that the gate would refuse, is not planned with. Which of the
    # two an unconverged fit is depends on the last bits of the arithmetic (the
    # machine's BLAS kernel), so the reason is not asserted, only that it is not used
    events = [r for r in ta if r["record"] == "event"]
    assert not [e for e in events if e["kind"] == "envelope"]
    assert any(e["kind"] == "warning" and e["message"].startswith(
        "model refit on 6 poses not used (") and e["message"].endswith(
        "planning stays with the model it had") for e in events)
    sim = ta[0]["station"]["simulator"]
    assert sim["seed"] == 20240501 and sim["pose_noise"] is True   # the truth file's
    assert "seed 20240501" in ra.stdout
    # pose lines carry their units (mm, degrees, actuator units)
    line = next(ln for ln in ra.stdout.splitlines() if ln.startswith("pose 1 of "))
    assert " mm" in line and "\u00b0" in line and "qm1 " in line and " u," in line
    # --sim-seed gives other noise, recorded too
    assert rc.returncode == 0, rc.stderr
    assert values(c) != values(a)
    assert records(c / "trace.jsonl")[0]["station"]["simulator"]["seed"] == 5
    # the finished folder again: the result shown, nothing appended, files untouched
    before = (a / "trace.jsonl").read_bytes(), (a / "params.json").read_bytes()
    again = run(a)
    assert again.returncode == 0, again.stderr
    assert "is finished" in again.stdout and "validation distance" in again.stdout
    assert ((a / "trace.jsonl").read_bytes(), (a / "params.json").read_bytes()) == before


def test_interrupt_says_what_is_kept_and_how_to_resume(tmp_path):
    out = tmp_path / "run"
    # 40 poses: the interrupt comes while it is measuring, however slow the machine.
    # Ctrl-C's default action in the child: a suite started in the background (by a
    # non-interactive shell, `cmd &`) passes SIGINT on ignored, and Python keeps it so
    p = subprocess.Popen([sys.executable, os.path.join(ROOT, "app.py"), *COMMAND,
                          "--count", "40", *quick(tmp_path), "--out", str(out)],
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT,
                         preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    try:
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline:   # wait for two recorded poses
            trace = out / "trace.jsonl"
            if trace.exists() and sum(ln.endswith(b"\n") and b'"record":"pose"' in ln
                                      for ln in trace.read_bytes().splitlines(True)) >= 2:
                break
            time.sleep(0.02)
        p.send_signal(signal.SIGINT)
        _, err = p.communicate(timeout=60)
    finally:
        if p.poll() is None:
            p.kill()
    kept = sum(r["record"] == "pose" for r in records(out / "trace.jsonl"))
    assert p.returncode == 130
    last = err.strip().splitlines()[-1]
    assert last.startswith(f"interrupted: {kept} poses recorded in {out / 'trace.jsonl'} are kept")
    assert "resume with: python " in last and "--out " + str(out) in last
