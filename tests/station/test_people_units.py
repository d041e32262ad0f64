"""Numbers for people (issue 23, findings 6 and 7): the console's parameter table,
sigma and fit-quality lines in mm and degrees with their units, the actuator unit
explained; the report's headline, convergence row, parameter units and plan rounds."""
from __future__ import annotations

import os
import re

from station.outputs.report_sections import plan_view
from tests.station.test_cli import TRACES, app

DRAWN = os.path.join(TRACES, "sm-distance-tilt-drawn-9300.jsonl")


def test_console_table_speaks_mm_and_degrees(tmp_path):
    r = app("batch", DRAWN, "--out", str(tmp_path / "p.json"), "--report",
            str(tmp_path / "r.html"))
    assert r.returncode == 0, r.stderr
    lines = r.stdout.splitlines()
    assert lines[0].split()[:3] == ["parameter", "unit", "start"]
    rows = {ln.split()[0]: ln.split()[1] for ln in lines[2:16]}
    assert rows["L2"] == "mm" and rows["theta0"] == "\u00b0" and rows["k2"] == "\u00b0/u"
    assert rows["k1"] == "mm/u"
    sigma = next(ln for ln in lines if ln.startswith("sigma"))
    assert re.search(r"distance [0-9.e+-]+ mm", sigma) and re.search(r"tilt [0-9.e+-]+\u00b0", sigma)
    rms = next(ln for ln in lines if ln.startswith("residual RMS"))
    assert " mm" in rms and "\u00b0" in rms
    assert any(ln.startswith("unit u: the actuator unit") for ln in lines)
    checks = [ln for ln in lines if ln.startswith(("ok: validation", "ok: noise"))]
    assert checks and all(" mm" in ln or "\u00b0" in ln for ln in checks), checks

    html = (tmp_path / "r.html").read_text()
    head = html[html.index("<h1>"):html.index('id="summary"')]
    assert 'class="headline top"' in head and "After calibration the robot reads within" in head
    assert "held-out poses never used in the fit" in head
    assert "converged converged" not in html
    params = html[html.index('id="parameters"'):]
    assert "<td>mm</td>" in params and "<td>\u00b0</td>" in params and "<td>rad</td>" not in params
    assert "u = the actuator unit of qm" in params


def test_plan_rounds_are_labelled_as_they_were_planned():
    arm = plan_view(1, {"kind": "plan", "box_scale": 0.3, "message": "m"},
                     [{"index": i, "qm": [0], "target": [0], "round": r}
                      for i, r in enumerate((0, 1, 2))])
    assert [p["round"] for p in arm["poses"]] == ["scout", "round 1", "round 2"]
    assert arm["rounds"] and "wrist" not in arm["rounds_text"]
    wrist = plan_view(2, {"kind": "plan", "wrist": {"round": 1}, "message": "m"},
                       [{"index": 0, "qm": [0], "target": [0], "round": 1}])
    assert wrist["poses"][0]["round"] == "round 1" and "wrist" in wrist["rounds_text"]
    one = plan_view(3, {"kind": "plan", "message": "m"},
                     [{"index": 0, "qm": [0], "target": [0], "round": 0}])
    assert not one["rounds"]
