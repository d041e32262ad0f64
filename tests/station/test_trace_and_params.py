"""Trace and parameter-file contracts (docs/file-formats.md)."""
import json
import os
import shutil

import numpy as np
import pytest

from calibration.errors import CalibrationError, TraceFormatError
from station.fitting.batch import calibrate_trace
from station.outputs.params_file import checksum, read_params, write_params
from station.recording.trace import TruncatedLineWarning, read_trace
from station.recording.trace_writer import TraceWriter

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
FIXTURE = os.path.join(ROOT, "fixtures", "traces", "sm-distance-tilt.jsonl")


def lines_of(path):
    with open(path) as f:
        return f.read().splitlines()


def write_lines(path, lines, newline=True):
    with open(path, "w") as f:
        f.write("\n".join(lines) + ("\n" if newline else ""))


@pytest.fixture
def trace_lines():
    return lines_of(FIXTURE)


@pytest.mark.parametrize("name", sorted(os.listdir(os.path.join(ROOT, "fixtures", "traces"))))
def test_fixture_traces_read(name):
    t = read_trace(os.path.join(ROOT, "fixtures", "traces", name))
    assert t.poses and t.header["format"] == "calstation-trace"


def test_malformed_line_is_named(tmp_path, trace_lines):
    trace_lines[5] = trace_lines[5][:-3] + "xx}"
    p = tmp_path / "t.jsonl"
    write_lines(p, trace_lines)
    with pytest.raises(TraceFormatError, match=r"t\.jsonl:6: not valid JSON"):
        read_trace(p)


def test_truncated_last_line_is_skipped_with_warning(tmp_path, trace_lines):
    p = tmp_path / "t.jsonl"
    write_lines(p, trace_lines[:-1] + [trace_lines[-1][:20]], newline=False)
    with pytest.warns(TruncatedLineWarning, match="truncated"):
        t = read_trace(p)
    assert len(t.poses) == len(trace_lines) - 3  # header, reference, cut pose


@pytest.mark.parametrize("field,value,message", [
    ("format", "other", "format must be"),
    ("version", 2, "unsupported trace version 2"),
    ("robot", "puma", "unknown robot"),
    ("method", "sm-laser", "unknown method"),
])
def test_bad_header(tmp_path, trace_lines, field, value, message):
    h = json.loads(trace_lines[0])
    h[field] = value
    trace_lines[0] = json.dumps(h)
    p = tmp_path / "t.jsonl"
    write_lines(p, trace_lines)
    with pytest.raises(TraceFormatError, match=message) as e:
        read_trace(p)
    assert ":1:" in str(e.value)


@pytest.mark.parametrize("mutate,message", [
    (lambda r: r.pop("distance"), "no 'distance' reading"),
    (lambda r: r.update(distance=float("nan")), "finite number"),
    (lambda r: r.update(tilt=float("inf")), "finite number"),
    (lambda r: r.update(qm=[1, 2]), "qm must be a list of 4"),
])
def test_bad_pose(tmp_path, trace_lines, mutate, message):
    rec = json.loads(trace_lines[4])
    mutate(rec)
    trace_lines[4] = json.dumps(rec)
    p = tmp_path / "t.jsonl"
    write_lines(p, trace_lines)
    with pytest.raises(TraceFormatError, match=message) as e:
        read_trace(p)
    assert ":5:" in str(e.value)


def test_too_few_poses_says_the_minimum(tmp_path, trace_lines):
    p = tmp_path / "t.jsonl"
    write_lines(p, trace_lines[:7])
    with pytest.raises(CalibrationError, match=r"at least 7 poses are needed \(recommended 33"):
        calibrate_trace(str(p), out=str(tmp_path / "p.json"))
    assert not (tmp_path / "p.json").exists()


def test_non_convergence_writes_no_file(tmp_path):
    from calibration.solver import SolverOptions

    out = tmp_path / "p.json"
    with pytest.raises(CalibrationError, match="did not converge"):
        calibrate_trace(FIXTURE, out=str(out), options=SolverOptions(max_iter=2))
    assert not out.exists()


def test_params_file_roundtrip_and_checksum(tmp_path):
    out = tmp_path / "p.json"
    outcome = calibrate_trace(FIXTURE, out=str(out))
    doc = read_params(out)
    assert doc["method"] == "sm-distance-tilt" and doc["fit"]["converged"]
    assert doc["frame"]["origin_qm"] == read_trace(FIXTURE).reference["qm"]
    assert doc["source_trace"]["file"] == "sm-distance-tilt.jsonl"
    assert set(doc["covariance"]["names"]) == set(doc["parameters"])
    a0 = doc["parameters"]["a0"]
    assert a0["identifiable"] and a0["std"] > 0
    assert np.isclose(a0["value"], outcome.result.value("a0"))
    # an edited file is detected
    text = out.read_text().replace(repr(a0["value"]), repr(a0["value"] + 1e-3))
    out.write_text(text)
    with pytest.raises(TraceFormatError, match="checksum does not match"):
        read_params(out)


def test_params_writer_is_atomic(tmp_path):
    out = tmp_path / "p.json"
    write_params(out, {"format": "calstation-params", "version": 1})
    before = out.read_bytes()
    with pytest.raises(ValueError):
        write_params(out, {"bad": float("nan")})
    assert out.read_bytes() == before
    assert [p.name for p in tmp_path.iterdir()] == ["p.json"]


def test_writer_resume_cuts_partial_line(tmp_path, trace_lines):
    p = tmp_path / "t.jsonl"
    shutil.copy(FIXTURE, p)
    with open(p, "ab") as f:
        f.write(b'{"record":"pose","ind')
    w = TraceWriter.resume(p)
    n = len(w.trace.poses)
    rec = json.loads(trace_lines[-1])
    rec["index"] += 1
    w.append(rec)
    w.close()
    assert len(read_trace(p).poses) == n + 1


@pytest.mark.parametrize("name", ["sm-distance-tilt.jsonl", "pm-tilt.jsonl"])
def test_fit_poses_counts_poses_not_rows(tmp_path, name):
    """fit.poses is the number of fit poses of the trace (a pose of sm-distance-tilt
    gives two rows, distance and tilt; pm-tilt two, roll and pitch)."""
    src = os.path.join(ROOT, "fixtures", "traces", name)
    out = tmp_path / "p.json"
    calibrate_trace(src, out=str(out))
    doc = read_params(out)
    fit = [r for r in map(json.loads, open(src, encoding="utf-8"))
           if r.get("record") == "pose" and r.get("use", "fit") == "fit"]
    assert doc["fit"]["poses"] == len(fit)
    assert doc["fit"]["rows"] == 2 * len(fit)


def test_pm_tilt_parameter_file_names_the_heading_as_not_identified(tmp_path):
    """pm-tilt identifies every parameter but not the heading about the vertical: the
    file states it with its std (read back through the schema), the table says it;
    pm-fk, which reads the heading, states nothing."""
    from station.outputs.fit_summary import format_table
    from station.outputs.report import write_outputs

    out = tmp_path / "tilt.json"
    outcome = calibrate_trace(os.path.join(ROOT, "fixtures", "traces", "pm-tilt.jsonl"),
                              out=str(out))
    doc = read_params(out)
    (d,) = doc["not_identified"]
    assert d["direction"] == "heading" and d["box_deg"] == 15.0
    assert 0 < d["std_rad"] < 0.05 and d["ik_std_modulo_heading"] < d["ik_std"]
    assert any("heading" in n for n in doc["notes"])
    assert "not identified: heading" in format_table(outcome)
    write_outputs(outcome, outcome.trace.path, tmp_path / "again.json", report=tmp_path / "r.html")
    assert "not identified: heading" in (tmp_path / "r.html").read_text()
    fk = tmp_path / "fk.json"
    calibrate_trace(os.path.join(ROOT, "fixtures", "traces", "pm-fk.jsonl"), out=str(fk))
    assert "not_identified" not in read_params(fk)
    bad = dict(doc, not_identified=[{"direction": "heading", "statement": "x", "std_rad": -1}])
    bad["checksum"] = checksum(bad)
    (tmp_path / "bad.json").write_text(json.dumps(bad))
    with pytest.raises(TraceFormatError, match="not_identified"):
        read_params(tmp_path / "bad.json")


def _remeasured(trace_lines, of: int, **change):
    """``trace_lines`` with pose ``of`` measured again at the end (its readings changed
    by ``change``): the new record and its index."""
    poses = [json.loads(ln) for ln in trace_lines if '"record": "pose"' in ln
             or '"record":"pose"' in ln]
    old = next(p for p in poses if p["index"] == of)
    new = dict(old, index=poses[-1]["index"] + 1, remeasure_of=of, **change)
    return trace_lines + [json.dumps(new)], new


def test_a_pose_measured_again_is_fitted_by_its_newest_reading(tmp_path, trace_lines):
    """A pose record with ``remeasure_of`` (issue 40: a flagged reading measured again at
    the robot) sets the reading it names aside: the trace keeps both, every calibration
    takes the newest. A reading 5 mm off, measured again as it is, calibrates as the
    trace without it."""
    base = tmp_path / "base.jsonl"
    write_lines(base, trace_lines)
    first = read_trace(str(base))
    k = first.fit_poses[3]["index"]
    recs = [json.loads(ln) for ln in trace_lines]
    off = [json.dumps(dict(r, distance=r["distance"] + 0.005)) if r["record"] == "pose"
           and r["index"] == k else ln for r, ln in zip(recs, trace_lines)]
    lines, new = _remeasured(off, k, distance=first.fit_poses[3]["distance"])
    path = tmp_path / "again.jsonl"
    write_lines(path, lines)
    tr = read_trace(str(path))
    assert tr.remeasured == {k: new["index"]} and len(tr.poses) == len(first.poses) + 1
    assert [p["index"] for p in tr.fit_poses] == [p["index"] for p in first.fit_poses
                                                   if p["index"] != k] + [new["index"]]
    assert [p["index"] for p in tr.readings_of(new["index"])] == [k, new["index"]]
    a, b = calibrate_trace(str(base)), calibrate_trace(str(path))
    np.testing.assert_allclose(b.result.x, a.result.x, rtol=1e-9, atol=1e-12)
    # measured a third time: the chain stays whole
    lines3, third = _remeasured(lines, new["index"])
    write_lines(path, lines3)
    tr = read_trace(str(path))
    assert [p["index"] for p in tr.readings_of(third["index"])] == [k, new["index"],
                                                                     third["index"]]


@pytest.mark.parametrize("change, message", [
    ({"remeasure_of": 999}, "remeasure_of must be the index of an earlier pose record"),
    ({"remeasure_of": "3"}, "remeasure_of must be the index of an earlier pose record"),
    ({"use": "validation"}, "so its use must be 'fit'"),
    ({"plan_index": 77}, "so its plan_index must be"),
])
def test_a_bad_remeasure_of_is_named_with_its_line(tmp_path, trace_lines, change, message):
    base = tmp_path / "base.jsonl"
    write_lines(base, trace_lines)
    k = read_trace(str(base)).fit_poses[2]["index"]
    lines, new = _remeasured(trace_lines, k)
    rec = {**new, **change}
    lines[-1] = json.dumps(rec)
    path = tmp_path / "bad.jsonl"
    write_lines(path, lines)
    with pytest.raises(TraceFormatError, match=message) as e:
        read_trace(str(path))
    assert f":{len(lines)}" in str(e.value)
    # the same reading measured again twice
    twice = trace_lines + [json.dumps(new), json.dumps(dict(new, index=new["index"] + 1))]
    write_lines(path, twice)
    with pytest.raises(TraceFormatError, match=f"pose {k} was measured again already"):
        read_trace(str(path))
