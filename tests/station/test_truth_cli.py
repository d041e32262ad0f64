"""Truth files from the command line (issue 23, findings 8 and 9): ``truth draw``
around a robot file, the "a truth is needed" message saying how, a truth file of
another robot refused in one line (no traceback), a conditioning warning said once."""
from __future__ import annotations

import json
import os
import sys
import warnings

import numpy as np

from drivers.sim.truth import load_truth
from tests.station.test_cli import ROOT, app

HAYATI = os.path.join(ROOT, "fixtures", "robots", "ur5-like-hayati.toml")


def test_truth_draw_around_a_robot_file(tmp_path):
    from drivers.sim.station_files import truth_of

    out = tmp_path / "truth.json"
    r = app("truth", "draw", "--robot", HAYATI, "--seed", "5", "--out", str(out))
    assert r.returncode == 0, r.stderr
    assert f"truth written to {out}" in r.stdout and "--truth" in r.stdout
    t = truth_of(HAYATI, str(out))           # of this robot file
    model = t.model()
    assert t.seed == 5 and t.noise and t.inclinometer_mount != (0.0, 0.0)
    assert not np.allclose(t.xi(), model.nominal)
    k = [j for j, n in enumerate(model.param_names) if n in model.fixed]
    assert k and np.allclose(t.xi()[k], model.nominal[k])     # k1..k6 held as the file says
    # the same seed draws the same robot; the spread options are the study's
    again = tmp_path / "again.json"
    assert app("truth", "draw", "--robot", HAYATI, "--seed", "5", "--out",
               str(again)).returncode == 0
    assert json.loads(again.read_text())["parameters"] == json.loads(out.read_text())["parameters"]
    tight = tmp_path / "tight.json"
    assert app("truth", "draw", "--robot", HAYATI, "--seed", "5", "--out", str(tight),
               "--gear", "0", "--length", "0", "--offset", "0").returncode == 0
    assert np.allclose(load_truth(tight).xi(), model.nominal)
    bad = app("truth", "draw", "--robot", HAYATI, "--out", str(tmp_path / "b.json"),
              "--length", "2")
    assert bad.returncode == 2 and bad.stderr.startswith("error: --length 2")
    assert not (tmp_path / "b.json").exists()


def test_wizard_draw_one_is_the_cli_draw(tmp_path):
    from station.gui.pages.setup import draw_truth_file

    path = draw_truth_file(HAYATI, tmp_path / "session", 11)
    r = app("truth", "draw", "--robot", HAYATI, "--seed", "11", "--out",
            str(tmp_path / "cli.json"))
    assert r.returncode == 0
    assert load_truth(path).parameters == load_truth(tmp_path / "cli.json").parameters


def test_a_truth_is_needed_says_how(tmp_path):
    r = app("run", "--simulate", "--robot", HAYATI, "--method", "sm-distance", "--out",
            str(tmp_path / "s"))
    assert r.returncode == 2
    line, = r.stderr.strip().splitlines()
    assert "needs --truth" in line and f"python app.py truth draw --robot {HAYATI}" in line


def test_truth_of_another_robot_refused_in_one_line(tmp_path):
    other = os.path.join(ROOT, "fixtures", "truth", "agebot-sm.json")
    r = app("run", "--simulate", "--robot", HAYATI, "--method", "sm-distance", "--truth",
            other, "--out", str(tmp_path / "s"))
    assert r.returncode == 2, r.stderr
    line, = r.stderr.strip().splitlines()
    assert line.startswith("error: ") and "Traceback" not in r.stderr
    assert "not of the robot file" in line and "agebot-sm" in line
    pm = os.path.join(ROOT, "fixtures", "truth", "agebot-pm.json")
    r = app("simulate", "--robot", "agebot-sm", "--truth", pm)
    assert r.returncode == 2 and "Traceback" not in r.stderr
    # the simulator's process refusing to start is a one-line error for its caller too
    from calibration.errors import StationError
    from drivers.sim.server import SimulatorProcess

    try:
        SimulatorProcess(HAYATI, truth=other)
    except StationError as e:
        assert "the simulator did not start" in str(e) and "\n" not in str(e)
    else:
        raise AssertionError("started with a truth file of another robot")


def test_conditioning_warning_said_once_without_a_source_line(monkeypatch, capsys, tmp_path):
    """The headless run prints the table's note; the warning behind it is not printed
    again (with the file and line that raised it) on stderr."""
    from station import headless
    from station.fitting import batch
    from station.outputs import fit_summary

    note = "joints 2 and 3 of x have (nearly) parallel axes: d2 is ill-conditioned there"

    class FakeSession:
        finished = resumed = False
        measured, validation, outcome = {}, [], None

        def __init__(self, *a, **k):
            pass

        def __enter__(self):
            return self

        def __exit__(self, *exc):
            return False

        def run(self):
            warnings.warn(note, batch.ConditioningWarning, stacklevel=2)
            return {"trace": "t", "params": "p", "checksum": "c", "report": "r"}

    monkeypatch.setattr(headless, "Session", FakeSession)
    monkeypatch.setattr(fit_summary, "format_table", lambda outcome: f"note: {note}")
    with warnings.catch_warnings():
        warnings.simplefilter("default")
        # as outside pytest (which records warnings): a shown warning goes to stderr
        warnings.showwarning = (lambda m, c, f, n, file=None, line=None: sys.stderr.write(
            warnings.formatwarning(m, c, f, n, line)))
        assert headless._session(None, "sm-distance", tmp_path, None, {}, None, None, None,
                                 None, None) == 0
    out, err = capsys.readouterr()
    assert out.count(note) == 1 and "ConditioningWarning" not in err and note not in err
