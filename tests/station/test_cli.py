"""The command-line contract (docs/cli.md), run as a user would."""
import os
import subprocess
import sys

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
TRACES = os.path.join(ROOT, "fixtures", "traces")


def app(*args, cwd=None):
    return subprocess.run([sys.executable, os.path.join(ROOT, "app.py"), *args],
                          capture_output=True, text=True, cwd=cwd or ROOT, timeout=120)


@pytest.mark.parametrize("name", sorted(os.listdir(TRACES)))
def test_batch_every_fixture_and_verify(tmp_path, name):
    out = tmp_path / "params.json"
    r = app("batch", os.path.join(TRACES, name), "--out", str(out))
    assert r.returncode == 0, r.stderr
    assert "identifiable" in r.stdout and "parameter file written" in r.stdout
    v = app("params", "verify", str(out))
    assert v.returncode == 0 and "OK" in v.stdout


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
