"""``python app.py ARGS`` in the test's own process, as the CLI tests run it."""
from __future__ import annotations

import app as app_module


def run(capsys, *args):
    """``(rc, stdout, stderr)`` of ``app.py ARGS``."""
    rc = app_module.main([str(a) for a in args])
    out = capsys.readouterr()
    return rc, out.out, out.err


def refused(capsys, args, *words):
    """Exit 2 with one line on stderr, ``error: ...``, holding every word and no numpy
    repr; returns the line."""
    rc, out, err = run(capsys, *args)
    lines = err.strip().splitlines()
    assert rc == 2 and len(lines) == 1 and lines[0].startswith("error: "), (out, err)
    assert "np.float64" not in lines[0] and "array(" not in lines[0], lines[0]
    for w in words:
        assert w in lines[0], lines[0]
    return lines[0]
