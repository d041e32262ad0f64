"""What each robot parameter buys (issue 42, item 3; :mod:`station.fitting.selection`):
stated in the parameter file and the console, every parameter still calibrated."""
from __future__ import annotations

import json

import app as app_module
from tests.station.urdf_helpers import import_args, tracker_case


def test_a_drawn_arm_states_what_each_parameter_buys(tmp_path, capsys):
    """A drawn arm (lengths and angles off their nominal), tracker noise: most robot
    parameters are clearly needed to predict the poses the fit has not seen, none is
    held, every one carries its t and both tails."""
    tracker_case(tmp_path, seed=5)
    assert app_module.main(import_args(tmp_path)) == 0
    assert app_module.main(["batch", str(tmp_path / "t.jsonl"),
                            "--out", str(tmp_path / "p.json")]) == 0
    out = capsys.readouterr().out
    line = next(ln for ln in out.splitlines() if "each robot parameter held" in ln)
    assert line.startswith("ok: ") and line.endswith("; all calibrated")
    doc = json.loads((tmp_path / "p.json").read_text())
    sel = next(c for c in doc["fit"]["quality"]["checks"] if c["check"] == "selection")
    judged = sel["selection"]["parameters"]
    assert judged and all({"name", "t", "p_held_better", "p_held_worse"} <= set(p)
                          for p in judged)
    assert not any(p["name"].startswith(("base_", "marker")) for p in judged)
    assert len(sel["selection"]["worth"]) > len(judged) / 2, line
    for p in judged:         # stated, not held: every judged parameter was calibrated
        assert doc["parameters"][p["name"]].get("identifiable", True) is not False
