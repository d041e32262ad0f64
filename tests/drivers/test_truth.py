"""Simulator truth files: fixtures, round trip, errors naming the file and key."""
from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest

from calibration.errors import ConfigError
from calibration.robots import get_robot
from drivers.sim.truth import (SimTruth, load_truth, parse_truth, report_truth, save_truth,
                               truth_to_dict)

TRUTH = Path(__file__).resolve().parents[2] / "fixtures" / "truth"


def fixture(name):
    return json.loads((TRUTH / f"{name}.json").read_text())


@pytest.mark.parametrize("robot", ["agebot-sm", "agebot-pm"])
def test_report_fixtures_hold_the_reports_true_values(robot):
    t = load_truth(TRUTH / f"{robot}.json")
    model = get_robot(robot)
    assert t.robot == robot and t.source.endswith(f"{robot}.json")
    assert tuple(t.parameters) == model.param_names
    np.testing.assert_allclose(t.xi(), model.true, rtol=1e-12)
    np.testing.assert_allclose(t.xi(), report_truth(robot).xi(), rtol=1e-12)
    assert t.seed is not None and t.sigma("distance") > 0 and t.sigma("qm") == 0.0
    assert t.without_noise().sigma("tilt") == 0.0 and t.sigma("tilt") > 0


@pytest.mark.parametrize("robot", ["agebot-sm", "agebot-pm"])
def test_unseen_fixtures_differ_by_a_few_percent(robot):
    t = load_truth(TRUTH / f"{robot}-unseen.json")
    true = get_robot(robot).true
    rel = np.abs(t.xi() / true - 1)
    assert np.all(rel > 1e-3), "every value must differ from the report's"
    assert np.all(rel < 0.1)


def test_plane_and_mount():
    sm = load_truth(TRUTH / "agebot-sm.json")
    assert sm.plane == (-0.19, -0.63, -0.06) and "plane_a" not in sm.parameters
    pm = load_truth(TRUTH / "agebot-pm-unseen.json")
    assert pm.inclinometer_mount == (0.004, -0.0025) and pm.plane is None
    assert load_truth(TRUTH / "agebot-pm.json").inclinometer_mount == (0.0, 0.0)


@pytest.mark.parametrize("name", ["agebot-sm", "agebot-pm", "agebot-sm-unseen", "agebot-pm-unseen"])
def test_round_trip(name, tmp_path):
    t = load_truth(TRUTH / f"{name}.json")
    assert truth_to_dict(t) == fixture(name)
    save_truth(t, tmp_path / "t.json")
    back = load_truth(tmp_path / "t.json")
    assert back == SimTruth(**{**t.__dict__, "source": str(tmp_path / "t.json")})
    assert [p.name for p in tmp_path.iterdir()] == ["t.json"]


def test_minimal_file_defaults():
    d = {"robot": "agebot-pm", "parameters": report_truth("agebot-pm").parameters}
    t = parse_truth(json.loads(json.dumps({**d, "parameters": dict(d["parameters"])})))
    assert t.noise == {} and t.seed is None and t.inclinometer_mount == (0.0, 0.0)
    assert t.sigma("roll") == 0.0


def error_of(data, source="truth.json") -> str:
    with pytest.raises(ConfigError) as e:
        parse_truth(data, source)
    return str(e.value)


@pytest.mark.parametrize("name,mutate,expected", [
    ("agebot-sm", lambda d: d["parameters"].pop("k3"), r"parameters\.k3: missing required key"),
    ("agebot-sm", lambda d: d["parameters"].update(L5=1.0), r"parameters\.L5: unknown parameter for agebot-sm"),
    ("agebot-sm", lambda d: d["parameters"].update(L2="long"), r"parameters\.L2: expected a finite number"),
    ("agebot-sm", lambda d: d["parameters"].pop("plane_b"), r"parameters\.plane_b: missing required key"),
    ("agebot-sm", lambda d: d["parameters"].update(plane_a=0, plane_b=0, plane_c=0), r"parameters\.plane_a: a plane"),
    ("agebot-pm", lambda d: d["parameters"].update(plane_a=0.1), r"parameters\.plane_a: unknown parameter for agebot-pm"),
    ("agebot-sm", lambda d: d["noise"].update(phi=0.1), r"noise\.phi: unknown channel"),
    ("agebot-sm", lambda d: d["noise"].update(tilt=-0.1), r"noise\.tilt: -0\.1 must be >= 0"),
    ("agebot-sm", lambda d: d.update(seed=1.5), r"seed: expected an integer"),
    ("agebot-sm", lambda d: d.update(robot="agebot-xx"), r"robot: 'agebot-xx' is not one of"),
    ("agebot-sm", lambda d: d.update(inclinometer_mount=[0.0, 0.0]), r"inclinometer_mount: only the agebot-pm"),
    ("agebot-pm", lambda d: d.update(inclinometer_mount=[0.01]), r"inclinometer_mount: expected a list of 2"),
    ("agebot-pm", lambda d: d.update(inclinometer_mount=[0.01, 2.0]), r"inclinometer_mount: a mounting rotation is small"),
    ("agebot-pm", lambda d: d.update(inclinometer_mount=[0.01, None]), r"inclinometer_mount\[1\]: expected a finite"),
    ("agebot-pm", lambda d: d.update(extra=1), r"extra: unknown key"),
    ("agebot-pm", lambda d: d.pop("parameters"), r"parameters: missing required key"),
])
def test_errors_name_file_and_key(name, mutate, expected):
    d = fixture(name)
    mutate(d)
    msg = error_of(d)
    assert msg.startswith("truth.json: "), msg
    assert re.search(expected, msg), msg


def test_file_errors(tmp_path):
    p = tmp_path / "broken.json"
    p.write_text("{\"robot\": ")
    with pytest.raises(ConfigError, match=r"broken\.json: not valid JSON"):
        load_truth(p)
    with pytest.raises(ConfigError, match=r"nothere\.json: cannot read"):
        load_truth(tmp_path / "nothere.json")
    p.write_text("[1, 2]")
    with pytest.raises(ConfigError, match=r"broken\.json: expected a table"):
        load_truth(p)
