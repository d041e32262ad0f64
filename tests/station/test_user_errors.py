"""A user's mistake gives one line on stderr naming what is wrong, a non-zero exit and
nothing left behind; never a traceback (issue: "No traceback for a user's mistake")."""
import errno
import hashlib
import json
import os
import shutil
import subprocess
import sys

import pytest

import app as app_module
from station.outputs.params_file import checksum, read_params

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
TRACE = os.path.join(ROOT, "fixtures", "traces", "sm-distance-tilt.jsonl")


def app(*args, cwd=None):
    return subprocess.run([sys.executable, os.path.join(ROOT, "app.py"), *args],
                          capture_output=True, text=True, cwd=cwd or ROOT, timeout=300)


def refused(r, *words):
    """rc != 0, one line on stderr starting 'error: ' and holding every word."""
    assert r.returncode != 0, r.stdout
    assert "Traceback" not in r.stderr, r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), r.stderr
    for w in words:
        assert w in lines[0], lines[0]
    return lines[0]


def digest(path):
    return hashlib.sha256(open(path, "rb").read()).hexdigest()


@pytest.fixture
def trace(tmp_path):
    p = tmp_path / "trace.jsonl"
    shutil.copy(TRACE, p)
    return p


def test_out_equal_to_the_input_trace_is_refused(trace, tmp_path):
    before = digest(trace)
    refused(app("batch", str(trace), "--out", str(trace)), "parameter file", "is the input")
    assert digest(trace) == before and os.listdir(tmp_path) == ["trace.jsonl"]


def test_report_equal_to_the_input_trace_is_refused(trace, tmp_path):
    before = digest(trace)
    refused(app("batch", str(trace), "--out", str(tmp_path / "p.json"), "--report", str(trace)),
            "report", "is the input")
    assert digest(trace) == before and os.listdir(tmp_path) == ["trace.jsonl"]


def test_report_equal_to_the_parameter_file_is_refused(trace, tmp_path):
    p = str(tmp_path / "p.json")
    refused(app("batch", str(trace), "--out", p, "--report", p), "also the parameter file")
    assert os.listdir(tmp_path) == ["trace.jsonl"]


def test_report_into_a_missing_folder_leaves_no_parameter_file(trace, tmp_path):
    refused(app("batch", str(trace), "--out", str(tmp_path / "p.json"), "--report",
                str(tmp_path / "nope" / "r.html")), "report", "does not exist")
    assert os.listdir(tmp_path) == ["trace.jsonl"]


def test_out_into_a_missing_folder_is_refused_before_the_fit(trace, tmp_path):
    line = refused(app("batch", str(trace), "--out", str(tmp_path / "nope" / "p.json")),
                   "parameter file", "does not exist")
    assert "nope" in line


def test_out_into_a_folder_that_cannot_be_written(trace, tmp_path):
    refused(app("batch", str(trace), "--out", "/proc/params.json"), "not writable")
    if os.geteuid() != 0:          # root writes into a 0555 folder
        ro = tmp_path / "ro"
        ro.mkdir(mode=0o555)
        refused(app("batch", str(trace), "--out", str(ro / "p.json")), "not writable")


def test_out_that_is_a_folder(trace, tmp_path):
    refused(app("batch", str(trace), "--out", str(tmp_path)), "is a folder")


def _no_space(*_a, **_k):
    raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))


def test_disk_full_writing_the_parameter_file(trace, tmp_path, monkeypatch, capsys):
    """ENOSPC from the parameter file's writer after the report was written: the
    report is removed again, nothing is left."""
    import station.outputs.params_file as pf

    monkeypatch.setattr(pf, "write_atomic", _no_space)
    rc = app_module.main(["batch", str(trace), "--out", str(tmp_path / "p.json"),
                          "--report", str(tmp_path / "r.html")])
    err = capsys.readouterr().err
    assert rc == 2 and err.startswith("error: ") and "No space left on device" in err
    assert len(err.strip().splitlines()) == 1
    assert sorted(os.listdir(tmp_path)) == ["trace.jsonl"]


def test_disk_full_at_the_fsync_leaves_no_temporary_file(trace, tmp_path, monkeypatch, capsys):
    import drivers.atomic as atomic

    real_fsync = os.fsync

    def fsync(fd):
        if os.path.basename(os.readlink(f"/proc/self/fd/{fd}")).startswith(".p.json"):
            _no_space()
        real_fsync(fd)

    monkeypatch.setattr(atomic.os, "fsync", fsync)
    rc = app_module.main(["batch", str(trace), "--out", str(tmp_path / "p.json")])
    err = capsys.readouterr().err
    assert rc == 2 and "No space left on device" in err and len(err.strip().splitlines()) == 1
    assert os.listdir(tmp_path) == ["trace.jsonl"]


@pytest.mark.parametrize("value,words", [("1e300", ("qm", "sane magnitude")),
                                         ("1" + "0" * 400, ("qm", "sane magnitude")),
                                         ("-1e400", ("qm", "sane magnitude", "-inf"))])
def test_huge_numbers_in_a_trace(tmp_path, value, words):
    lines = open(TRACE).read().splitlines()
    rec = json.loads(lines[4])
    lines[4] = json.dumps(rec).replace(json.dumps(rec["qm"][1]), value, 1)
    bad = tmp_path / "t.jsonl"
    bad.write_text("\n".join(lines) + "\n")
    line = refused(app("batch", str(bad), "--out", str(tmp_path / "p.json")), *words)
    assert "t.jsonl:5" in line and len(line) < 300
    assert not (tmp_path / "p.json").exists()


def test_deeply_nested_json_in_a_trace(tmp_path):
    lines = open(TRACE).read().splitlines()
    head = json.loads(lines[0])
    text = json.dumps(head)[:-1] + ', "station": ' + "[" * 100000 + "]" * 100000 + "}"
    bad = tmp_path / "t.jsonl"
    bad.write_text("\n".join([text] + lines[1:]) + "\n")
    refused(app("batch", str(bad), "--out", str(tmp_path / "p.json")), "t.jsonl:1",
            "nested too deeply")


def test_a_utf16_station_config(tmp_path):
    src = os.path.join(ROOT, "fixtures", "stations", "sim-sm.toml")
    cfg = tmp_path / "station.toml"
    cfg.write_bytes(open(src, encoding="utf-8").read().encode("utf-16"))
    refused(app("devices", "check", "--config", str(cfg), "--seconds", "0.1"),
            "station.toml", "UTF-8")


def test_trace_generate_into_a_missing_folder(tmp_path):
    refused(app("trace", "generate", "--method", "sm-distance", "--out",
                str(tmp_path / "nope" / "t.jsonl")), "the trace", "does not exist")
    assert os.listdir(tmp_path) == []


def test_trace_generate_with_a_noise_that_is_not_a_number(tmp_path):
    refused(app("trace", "generate", "--method", "sm-distance", "--out",
                str(tmp_path / "t.jsonl"), "--noise", "distance=abc"), "distance=abc")
    assert os.listdir(tmp_path) == []


# -- parameter files: structure and values, not only the checksum -----------------------
@pytest.fixture(scope="module")
def good_params(tmp_path_factory):
    d = tmp_path_factory.mktemp("params")
    out = d / "p.json"
    r = app("batch", TRACE, "--out", str(out))
    assert r.returncode == 0, r.stderr
    return json.loads(out.read_text())


def _write(tmp_path, doc, resign=True):
    doc = dict(doc)
    if resign:
        doc["checksum"] = checksum(doc)
    p = tmp_path / "p.json"
    p.write_text(json.dumps(doc))
    return p


@pytest.mark.parametrize("edit,words", [
    (lambda d: d.update(version=True), ("version True",)),
    (lambda d: d.update(parameters={}), ("parameters", "non-empty")),
    (lambda d: d.update(robot="agebot-xx"), ("robot", "agebot-xx")),
    (lambda d: d.update(parameters=[1, 2]), ("parameters", "not of type 'object'")),
    (lambda d: d["parameters"]["L2"].update(value="0.69"), ("parameters.L2.value", "number")),
    (lambda d: d["parameters"]["L2"].update(std=-1.0), ("parameters.L2.std",)),
    (lambda d: d["parameters"].update(L9=d["parameters"]["L2"]), ("unknown ['L9']",)),
    (lambda d: d.update(method="pm-fk"), ("method", "not a method of agebot-sm")),
    (lambda d: d["covariance"]["matrix"].pop(), ("covariance.matrix", "x")),
    (lambda d: d.update(fit="converged"), ("fit", "not of type 'object'")),
])
def test_params_verify_refuses_a_bad_structure_or_value(tmp_path, good_params, edit, words):
    doc = json.loads(json.dumps(good_params))
    edit(doc)
    p = _write(tmp_path, doc)
    refused(app("params", "verify", str(p)), "p.json", *words)


def test_params_verify_refuses_nan(tmp_path, good_params):
    text = json.dumps(good_params).replace(
        json.dumps(good_params["parameters"]["L2"]["value"]), "NaN", 1)
    p = tmp_path / "p.json"
    p.write_text(text)
    refused(app("params", "verify", str(p)), "NaN is not a JSON number")


def test_params_verify_refuses_deep_nesting(tmp_path, good_params):
    doc = dict(good_params)
    p = tmp_path / "p.json"
    p.write_text(json.dumps(doc)[:-1] + ', "x": ' + "[" * 100000 + "]" * 100000 + "}")
    refused(app("params", "verify", str(p)), "nested too deeply")


def test_a_good_parameter_file_still_verifies(tmp_path, good_params):
    p = _write(tmp_path, good_params, resign=False)
    assert read_params(p)["robot"] == "agebot-sm"
    assert app("params", "verify", str(p)).returncode == 0
