"""Durability observed from outside the writer, and the parameter file's
checksum against an independent computation (docs/file-formats.md).

* After every trace append a second process reads the file: the new line must
  be there already (the writer flushed), and the writer must have fsynced that
  file after the line reached it (observed by the real ``os.fsync``, wrapped).
* The checksum of a small parameter document is computed here with hashlib
  from the spec's canonical form (keys sorted, no whitespace), not by the
  function under test.
"""
import hashlib
import json
import os
import subprocess
import sys

import pytest

from calibration.errors import TraceFormatError
from station.outputs import params_file
from station.outputs.params_file import read_params, write_params
from station.recording.trace import read_trace
from station.recording.trace_writer import TraceWriter

READER = r"""
import sys
path = sys.argv[1]
for _ in sys.stdin:                      # one request per line: print the last line
    with open(path, "rb") as f:
        lines = f.read().split(b"\n")
    tail = lines[-2] if len(lines) > 1 and lines[-1] == b"" else b"<partial>"
    sys.stdout.write(tail.decode() + "\n")
    sys.stdout.flush()
"""

HEADER = {"robot": "agebot-sm", "method": "sm-distance", "nominal": {}}


def _pose(i):
    return {"record": "pose", "index": i, "qm": [0.1 * i, -0.2, 0.3, 0.01 * i],
            "distance": 0.5 + 1e-5 * i}


@pytest.fixture
def fsyncs(monkeypatch):
    """Every os.fsync: (inode, size of the file at that moment); the real fsync runs."""
    calls = []
    real = os.fsync

    def observed(fd):
        st = os.fstat(fd)
        calls.append((st.st_ino, st.st_size))
        return real(fd)

    monkeypatch.setattr(os, "fsync", observed)
    return calls


def test_every_append_is_visible_to_another_process_and_fsynced(tmp_path, fsyncs):
    path = tmp_path / "trace.jsonl"
    w = TraceWriter.create(path, HEADER)
    reader = subprocess.Popen([sys.executable, "-c", READER, str(path)], stdin=subprocess.PIPE,
                              stdout=subprocess.PIPE, text=True)
    try:
        ino = os.stat(path).st_ino
        assert fsyncs and fsyncs[-1] == (ino, os.stat(path).st_size)  # the header
        w.append({"record": "reference", "role": "reference-point", "qm": [0.0, 0.0, 0.0, 0.0]})
        for i in range(6):
            rec = _pose(i)
            fsyncs.clear()
            w.append(rec)
            size = os.stat(path).st_size
            # fsynced after the whole line was in the file, not before
            assert (ino, size) in fsyncs, (fsyncs, size)
            reader.stdin.write("?\n")
            reader.stdin.flush()
            seen = reader.stdout.readline().rstrip("\n")
            assert json.loads(seen) == rec
    finally:
        reader.stdin.close()
        reader.wait(timeout=30)
        w.close()
    assert len(read_trace(path).poses) == 6


def test_resume_cut_is_fsynced(tmp_path, fsyncs):
    path = tmp_path / "trace.jsonl"
    with TraceWriter.create(path, HEADER) as w:
        w.append({"record": "reference", "role": "reference-point", "qm": [0.0, 0.0, 0.0, 0.0]})
        w.append(_pose(0))
    whole = path.read_bytes()
    with open(path, "ab") as f:
        f.write(b'{"record":"pose","ind')
    fsyncs.clear()
    w = TraceWriter.resume(path)
    try:
        assert path.read_bytes() == whole
        assert (os.stat(path).st_ino, len(whole)) in fsyncs
    finally:
        w.close()


# The document below in the spec's canonical form, written out by hand: keys
# sorted at every level, no whitespace, floats as Python's repr, null for None.
DOC = {
    "version": 1,
    "format": "calstation-params",
    "robot": "agebot-sm",
    "method": "sm-distance",
    "created": "2026-11-23T17:00:00.000Z",
    "parameters": {
        "k1": {"value": 1.25, "nominal": 1.0, "std": None, "identifiable": False,
               "influences_model": False},
        "L2": {"value": -0.5, "nominal": -0.5, "std": 2e-05, "identifiable": True,
               "influences_model": False}},
    "fit": {"iterations": 7, "sigma": {"tilt": 0.00017, "distance": 1e-05}},
    "covariance": {"names": ["L2"], "matrix": [[4e-10]]},
}
CANONICAL = (b'{"covariance":{"matrix":[[4e-10]],"names":["L2"]},'
             b'"created":"2026-11-23T17:00:00.000Z",'
             b'"fit":{"iterations":7,"sigma":{"distance":1e-05,"tilt":0.00017}},'
             b'"format":"calstation-params","method":"sm-distance",'
             b'"parameters":{"L2":{"identifiable":true,"influences_model":false,"nominal":-0.5,'
             b'"std":2e-05,"value":-0.5},'
             b'"k1":{"identifiable":false,"influences_model":false,"nominal":1.0,"std":null,'
             b'"value":1.25}},'
             b'"robot":"agebot-sm","version":1}')
GOLDEN = "sha256:" + hashlib.sha256(CANONICAL).hexdigest()


def test_checksum_is_sha256_of_the_canonical_form():
    assert params_file.checksum(DOC) == GOLDEN
    # the checksum field itself is not part of what it covers
    assert params_file.checksum(dict(DOC, checksum="sha256:0")) == GOLDEN


def test_written_file_carries_the_independent_checksum(tmp_path):
    out = tmp_path / "p.json"
    write_params(out, DOC)
    assert json.loads(out.read_text())["checksum"] == GOLDEN
    assert read_params(out)["parameters"]["L2"]["std"] == 2e-05


def test_reader_checks_against_the_canonical_form(tmp_path):
    """A file whose checksum was made over another serialization (spaces after
    the separators) is refused; one made by hand over the canonical form is read."""
    ok, bad = tmp_path / "ok.json", tmp_path / "bad.json"
    spaced = json.dumps(DOC, sort_keys=True).encode()
    ok.write_text(json.dumps(dict(DOC, checksum=GOLDEN), indent=1))
    bad.write_text(json.dumps(dict(DOC, checksum="sha256:" + hashlib.sha256(spaced).hexdigest())))
    assert read_params(ok)["robot"] == "agebot-sm"
    with pytest.raises(TraceFormatError, match="checksum does not match"):
        read_params(bad)


def test_checksum_refuses_what_json_cannot_hold():
    """NaN and infinity are not JSON: no checksum, so no file, can be made over them."""
    for bad in (float("nan"), float("inf")):
        with pytest.raises(ValueError):
            params_file.checksum(dict(DOC, fit={"sigma": {"distance": bad}}))


def test_source_trace_hash_covers_the_whole_file(tmp_path):
    """The parameter file names its trace by the SHA-256 of every byte (read in chunks)."""
    data = os.urandom(200_000)
    p = tmp_path / "big.jsonl"
    p.write_bytes(data)
    assert params_file.file_sha256(p) == hashlib.sha256(data).hexdigest()


def test_trace_lines_are_compact_json_and_refuse_nan(tmp_path):
    path = tmp_path / "trace.jsonl"
    with TraceWriter.create(path, HEADER) as w:
        assert w.path == str(path)
        w.append({"record": "reference", "role": "reference-point", "qm": [0.0, 0.5, 0.0, 0.0]})
        before = path.read_bytes()
        with pytest.raises(ValueError):
            w.append({"record": "pose", "index": 0, "qm": [0.0, 0.0, 0.0, 0.0],
                      "distance": float("nan")})
        assert path.read_bytes() == before  # nothing of the refused record reached the file
    assert before.splitlines()[-1] == b'{"record":"reference","role":"reference-point","qm":[0.0,0.5,0.0,0.0]}'
    with pytest.raises(ValueError):  # closed on leaving the block
        w.append(_pose(0))
    resumed = TraceWriter.resume(path)
    try:
        assert resumed.path == str(path) and len(resumed.trace.poses) == 0
        resumed.append(_pose(0))
    finally:
        resumed.close()
    assert read_trace(path).poses[0]["index"] == 0
