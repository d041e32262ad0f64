"""The command-line contract (docs/cli.md), run as a user would."""
import hashlib
import json
import math
import os
import re
import subprocess
import sys

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
TRACES = os.path.join(ROOT, "fixtures", "traces")


def app(*args, cwd=None):
    return subprocess.run([sys.executable, os.path.join(ROOT, "app.py"), *args],
                          capture_output=True, text=True, cwd=cwd or ROOT, timeout=120)


#: the table's display units (mm and degrees for people) -> factor to SI
TO_SI = {"mm": 1e-3, "mm/u": 1e-3, "\u00b0": math.pi / 180, "\u00b0/u": math.pi / 180,
         "1": 1.0, "1/m": 1.0}


def parse_table(stdout):
    """The batch command's parameter table: name -> (start, calibrated, std or None, label)
    in SI (the printed unit column read back), and the figures under it (iterations,
    identifiable count, printed checksum)."""
    lines = stdout.splitlines()
    rules = [i for i, ln in enumerate(lines) if ln.startswith("-" * 20)]
    rows = {}
    for ln in lines[rules[0] + 1:rules[1]]:
        name, unit, start, value, std, label = ln.split(None, 5)
        f = TO_SI[unit]
        rows[name] = (float(start) * f, float(value) * f,
                      None if std == "-" else float(std) * f, label)
    tail = "\n".join(lines[rules[1]:])
    figures = {
        "iterations": int(re.search(r"converged in (\d+) iterations", tail).group(1)),
        "identifiable": tuple(map(int, re.search(r"identifiable (\d+) of (\d+)", tail).groups())),
        "checksum": re.search(r"parameter file written to .* \((sha256:[0-9a-f]{64})\)", tail).group(1),
    }
    return rows, figures


def _close6(printed, exact):
    """A value printed with 6 significant digits is the exact one."""
    return printed == pytest.approx(exact, rel=6e-6, abs=1e-300)


@pytest.mark.parametrize("name", sorted(os.listdir(TRACES)))
def test_batch_every_fixture_and_verify(tmp_path, name):
    out = tmp_path / "params.json"
    r = app("batch", os.path.join(TRACES, name), "--out", str(out))
    assert r.returncode == 0, r.stderr
    rows, figures = parse_table(r.stdout)
    with open(out) as f:
        doc = json.load(f)
    # the printed numbers are the file's: values, std, labels, counts, checksum
    assert sorted(rows) == sorted(doc["parameters"])
    for pname, (start, value, std, label) in rows.items():
        p = doc["parameters"][pname]
        assert _close6(start, p["nominal"]) and _close6(value, p["value"]), pname
        assert (std is None) == (p["std"] is None) and (std is None or _close6(std, p["std"])), pname
        assert label.startswith("identifiable") == p["identifiable"], pname
        assert ("influences the model" in label) == p["influences_model"], pname
    assert figures["iterations"] == doc["fit"]["iterations"] > 0
    n_id = sum(p["identifiable"] for p in doc["parameters"].values())
    assert figures["identifiable"] == (n_id, len(doc["parameters"]))
    body = {k: v for k, v in doc.items() if k != "checksum"}
    canonical = json.dumps(body, sort_keys=True, separators=(",", ":")).encode()
    assert figures["checksum"] == doc["checksum"] == "sha256:" + hashlib.sha256(canonical).hexdigest()
    v = app("params", "verify", str(out))
    assert v.returncode == 0, v.stderr
    assert f"{n_id} of {len(doc['parameters'])} parameters calibrated" in v.stdout
    assert f"method {doc['method']}" in v.stdout and doc["checksum"] in v.stdout


def test_batch_prints_the_calibration_of_the_trace(tmp_path):
    """The printed table is the solver's result on that trace (computed here in
    process), and that result recovers the report's truth the fixture was made from."""
    from calibration.robots import get_robot
    from station.fitting.batch import calibrate_trace

    trace = os.path.join(TRACES, "sm-distance.jsonl")
    r = app("batch", trace, "--out", str(tmp_path / "p.json"))
    assert r.returncode == 0, r.stderr
    rows, figures = parse_table(r.stdout)
    res = calibrate_trace(trace).result
    assert figures["iterations"] == res.iterations
    truth = get_robot("agebot-sm").true
    for j, (pname, st) in enumerate(zip(res.names, res.status)):
        start, value, std, _ = rows[pname]
        assert _close6(value, res.x[j]), pname
        if st.identifiable:
            assert _close6(std, res.std[j]) and abs(value - truth[j]) < 4 * std, pname
        else:
            assert std is None and value == start


def test_user_errors_are_one_line_without_traceback(tmp_path):
    bad = tmp_path / "bad.jsonl"
    bad.write_text('{"record": "header", "format": "calstation-trace", "version": 9}\n')
    out = tmp_path / "p.json"
    for args in (("batch", str(bad), "--out", str(out)),
                 ("batch", str(tmp_path / "missing.jsonl"), "--out", str(out)),
                 ("params", "verify", str(bad))):
        r = app(*args)
        assert r.returncode != 0
        assert "Traceback" not in r.stderr
        assert len(r.stderr.strip().splitlines()) == 1, r.stderr
        assert r.stderr.startswith("error: ")
    assert not out.exists()


def test_generate_then_batch(tmp_path):
    t = tmp_path / "t.jsonl"
    r = app("trace", "generate", "--method", "sm-distance", "--out", str(t), "--noise", "distance=1e-4")
    assert r.returncode == 0, r.stderr
    r = app("batch", str(t), "--out", str(tmp_path / "p.json"), "--residual", "squared")
    assert r.returncode == 0, r.stderr


def test_trace_generate_says_whether_it_is_noise_free(tmp_path):
    out = tmp_path / "t.jsonl"
    r = app("trace", "generate", "--method", "sm-distance", "--out", str(out), "--count", "10")
    assert r.returncode == 0, r.stderr
    assert "noise-free readings" in r.stdout and "--noise" in r.stdout
    r = app("trace", "generate", "--method", "sm-distance-tilt", "--out", str(out),
            "--count", "10", "--noise", "distance=1e-5", "--noise", "tilt=2e-4")
    assert r.returncode == 0, r.stderr
    assert "reading noise std: distance 0.01 mm, tilt 0.0115\u00b0" in r.stdout
    r = app("trace", "generate", "--help")
    assert "sm-distance-tilt" in r.stdout and "pm-fk" in r.stdout   # the choices
    r = app("trace", "generate", "--method", "sm-nope", "--out", str(out))
    assert r.returncode != 0 and "invalid choice" in r.stderr
