"""Robot files at the station: the reader's errors, traces that carry their robot
file, batch and trace generation from the command line, and AGEBOT's serial part
as a robot file reproducing the built-in model on the fixture traces."""
from __future__ import annotations

import json
import math
import os

import numpy as np
import pytest

from calibration.errors import ConfigError, TraceFormatError
from drivers.robot_file import load_robot_file, parse_robot_file
from station.fitting.batch import calibrate, calibrate_trace
from station.recording.trace import read_trace
from station.recording.trace_writer import write_trace
from tests.station.test_cli import ROOT, TRACES, app

ROBOTS = os.path.join(ROOT, "fixtures", "robots")
GOOD = """format = "calstation-robot"
version = 1
name = "two-link"
[[joint]]
type = "R"
d = 0.1
a = 0.5
limits = [-3.0, 3.0]
[[joint]]
type = "P"
a = 0.2
limits = [0.0, 0.3]
"""


def test_good_file_and_parameter_names():
    spec = parse_robot_file(GOOD, "two.toml")
    from calibration.robots import get_robot

    rob = get_robot(spec)
    assert rob.param_names[:4] == ("q1_off", "q2_off", "k1", "k2")
    assert {"d1", "a1", "alpha1", "theta2", "a2", "alpha2", "base_gamma", "tool_d"} <= set(rob.param_names)
    assert "d2" not in rob.param_names
    assert spec.source["name"] == "two.toml" and spec.source["text"] == GOOD


@pytest.mark.parametrize("edit,key,words", [
    (("limits = [0.0, 0.3]", "limits = [0.3, 0.0]"), "joint[2].limits", "lo < hi"),
    (("a = 0.2", "d = 0.1\na = 0.2"), "joint[2].d", "P joint has no 'd'"),
    (("a = 0.5", "a = 0.5\nbeta = 0.0"), "joint[1].beta", "no 'd'"),
    (("a = 0.5", "a = 0.5\nlenght = 2.0"), "joint[1].lenght", "unknown key"),
    (('type = "P"', 'type = "X"'), "joint[2].type", "is not one of"),
    (("version = 1", 'version = 1\nfixed = ["k9"]'), "fixed", "unknown parameter 'k9'"),
    (('name = "two-link"', 'name = "agebot-sm"'), "name", "built-in"),
    (("version = 1", "version = 2"), "version", "unsupported version"),
    (("limits = [-3.0, 3.0]", "limits = [-170, 170]"), "joint[1].limits", "look like degrees"),
])
def test_errors_name_the_file_the_key_and_the_fault(tmp_path, edit, key, words):
    path = tmp_path / "arm.toml"
    path.write_text(GOOD.replace(*edit, 1))
    with pytest.raises(ConfigError) as e:
        load_robot_file(path)
    msg = str(e.value)
    assert str(path) in msg and key in msg and words in msg and "\n" not in msg


def test_limits_in_degrees_refused_in_one_line_naming_the_key(tmp_path):
    """An R joint's limits written in degrees (issue 23, finding 5): refused by every
    command with one line naming the file and the key, the limits in radians said;
    a wide wrist (+-700 deg) and a fine gear (k small, qm large) are not."""
    path = tmp_path / "arm.toml"
    path.write_text(GOOD.replace("limits = [-3.0, 3.0]", "limits = [-170, 170]"))
    r = app("trace", "generate", "--robot", str(path), "--method", "sm-position",
            "--out", str(tmp_path / "t.jsonl"))
    assert r.returncode == 2 and r.stdout == ""
    line, = r.stderr.strip().splitlines()
    assert line.startswith("error: ") and f"{path}: joint[1].limits" in line
    assert "degrees" in line and "[-2.967, 2.967]" in line
    assert not (tmp_path / "t.jsonl").exists()
    parse_robot_file(GOOD.replace("limits = [-3.0, 3.0]", "limits = [-12.2, 12.2]"), "w.toml")
    parse_robot_file(GOOD.replace("limits = [-3.0, 3.0]", "k = 0.01\nlimits = [-300, 300]"),
                     "g.toml")
    for f in os.listdir(ROBOTS):
        if f.endswith(".toml"):
            load_robot_file(os.path.join(ROBOTS, f))


def test_trace_checksum_guards_the_robot_file(tmp_path):
    out = tmp_path / "t.jsonl"
    r = app("trace", "generate", "--robot", os.path.join(ROBOTS, "scara-like.toml"),
            "--method", "sm-position", "--noise", "position=1e-4", "--out", str(out))
    assert r.returncode == 0, r.stderr
    lines = out.read_text().splitlines()
    head = json.loads(lines[0])
    head["robot_file"]["text"] = head["robot_file"]["text"].replace("a = 0.35", "a = 0.36")
    bad = tmp_path / "bad.jsonl"
    bad.write_text("\n".join([json.dumps(head)] + lines[1:]) + "\n")
    with pytest.raises(TraceFormatError, match="sha256 does not match"):
        read_trace(bad)


def test_generate_and_batch_need_nothing_but_the_trace(tmp_path):
    t = tmp_path / "ur5.jsonl"
    r = app("trace", "generate", "--robot", os.path.join(ROBOTS, "ur5-like-hayati.toml"),
            "--method", "sm-full-pose", "--noise", "position=1e-4", "--out", str(t))
    assert r.returncode == 0, r.stderr
    assert "60" not in r.stderr
    p, html = tmp_path / "p.json", tmp_path / "r.html"
    r = app("batch", str(t), "--out", str(p), "--report", str(html), cwd=str(tmp_path))
    assert r.returncode == 0, r.stderr
    from station.outputs.units import param_units

    units = param_units(read_trace(t))
    assert units["beta2"] == "rad" and units["d4"] == "m" and units["k1"] == "rad/u"
    assert "beta2" in html.read_text() and "captured base origin" not in r.stdout
    assert "identifiable 30 of" in r.stdout and "held (the robot file's fixed)" in r.stdout
    doc = json.loads(p.read_text())
    assert doc["robot"] == "ur5-like-hayati" and "ur5-like-hayati" in doc["robot_file"]["text"]
    r = app("trace", "generate", "--robot", os.path.join(ROBOTS, "ur5-like-dh.toml"),
            "--method", "sm-position", "--out", str(tmp_path / "dh.jsonl"))
    r = app("batch", str(tmp_path / "dh.jsonl"), "--out", str(tmp_path / "dh.json"))
    assert r.returncode == 0 and "warning:" in r.stderr and "joints 2 and 3" in r.stderr


# -- AGEBOT's serial part as a robot file ----------------------------------------------
def _as_robot_file(trace, spec):
    """The agebot-sm trace as a trace of the robot file: same readings, the pose's
    phi as yaw (roll = pitch = 0), nominal (theta0, a0) as base_a = x0, a1 = y0."""
    h = dict(trace.header)
    nom = dict(h["nominal"])
    th, a0 = nom.pop("theta0"), nom.pop("a0")
    for i, L in enumerate(("L2", "L3", "L4"), start=2):
        nom[f"a{i}"] = nom.pop(L)
    nom["base_a"], nom["a1"] = a0 * math.cos(th), a0 * math.sin(th)
    h.update(robot=spec.name, robot_file=dict(spec.source), nominal=nom)
    for k in ("record", "format", "version", "created"):
        h.pop(k, None)
    poses = []
    for p in trace.poses:
        p = {k: v for k, v in p.items() if k != "record"}
        if "pose" in p:
            x, y, z, phi = p["pose"]
            p["pose"] = [x, y, z, 0.0, 0.0, phi]
        poses.append(p)
    ref = None if trace.reference is None else {k: v for k, v in trace.reference.items()
                                                if k != "record"}
    return h, ref, poses


@pytest.mark.parametrize("method", ["sm-full-pose", "sm-distance", "sm-plane",
                                    "sm-self-redundancy"])
def test_agebot_robot_file_reproduces_the_builtin_model(tmp_path, method):
    spec = load_robot_file(os.path.join(ROBOTS, "agebot-sm.toml"))
    built = calibrate_trace(os.path.join(TRACES, f"{method}.jsonl"))
    path = tmp_path / "file.jsonl"
    write_trace(path, *_as_robot_file(built.trace, spec))
    mine = calibrate(read_trace(path))
    xb, xf = built.result, mine.result
    assert xb.n_identifiable == xf.n_identifiable
    v = {n: xb.value(n) for n in xb.names}
    expect = {"q1_off": v["q1_off"], "q2_off": v["q2_off"], "q3_off": v["q3_off"],
              "q4_off": v["q4_off"], "k1": v["k1"], "k2": v["k2"], "k3": v["k3"], "k4": v["k4"],
              "a2": v["L2"], "a3": v["L3"], "a4": v["L4"],
              "base_a": v["a0"] * math.cos(v["theta0"]), "a1": v["a0"] * math.sin(v["theta0"])}
    # Both fits stop where the step falls below epsilon, by their own paths: the same
    # values to 1e-9. (Before the damping's floor gave way after well-predicted steps,
    # the robot file's sm-distance crawled along a direction weak against that floor,
    # 440 iterations, and stopped 1.8e-9 rad from the builtin's q3_off; with it, 49
    # iterations, until a rejected step was retried half as long or shorter, by the
    # parabola along it, instead of at a damping only ten times higher: 8, as lm.)
    assert xf.iterations <= 20, (xf.iterations, xf.message)
    for n, e in expect.items():
        assert abs(xf.value(n) - e) <= 1e-9 * max(1.0, abs(e)), (n, xf.value(n), e)
    # the std of one unit of sigma (an estimated sigma, sm-plane's noise-free trace, is
    # round-off: 2.354e-14 in one fit, 2.350e-14 in the other), to 1e-9; to 1e-7 where a
    # fit took its last step without evaluating the model after it (the step after it
    # predicted below epsilon): it forms the covariance one such step from its solution
    # (sm-distance's robot file: a largest component of 1.0e-9, its std 2.7e-9 off)
    unit_b = {xb.names[j]: xb.error_of(xb.names[j]) for j in range(len(xb.names))}
    sb, sf = max(xb.sigma.values()), max(xf.sigma.values())
    if sb > 1e-10:     # a noisy trace: the same sigma
        assert abs(sf / sb - 1) < 1e-9, (xb.sigma, xf.sigma)
    settled = any("predicted for the step after the last" in x.message for x in (xb, xf))
    tol = 1e-7 if settled else 1e-9
    for n in ("q3_off", "k2", "k3", "L2", "L3"):  # the same names in both models
        m = {"L2": "a2", "L3": "a3"}.get(n, n)
        if xb.status[xb.names.index(n)].identifiable:
            assert abs((xf.error_of(m) / sf) / (unit_b[n] / sb) - 1) < tol, n
    qm = np.array([p["qm"] for p in built.trace.poses])
    pb = built.model.robot.fk(qm, xb.x[:13])[:, :3]
    pf = mine.model.robot.fk(qm, xf.x[:mine.model.robot.n_params])[:, :3]
    # the tool's position
    assert np.abs(pb - pf).max() < 1e-9


# -- exports ---------------------------------------------------------------------------
def test_urdf_and_calibrated_robot_file_give_the_parameter_files_model(tmp_path):
    import yourdfpy

    from calibration.robots import get_robot
    from station.outputs.export import calibrated_model
    from station.outputs.params_file import read_params

    t, p = tmp_path / "t.jsonl", tmp_path / "p.json"
    r = app("trace", "generate", "--robot", os.path.join(ROBOTS, "ur5-like-hayati.toml"),
            "--method", "sm-position", "--noise", "position=1e-4", "--seed", "4", "--out", str(t))
    assert r.returncode == 0, r.stderr
    assert app("batch", str(t), "--out", str(p)).returncode == 0
    urdf, toml = tmp_path / "cal.urdf", tmp_path / "cal.toml"
    r = app("params", "export", str(p), "--urdf", str(urdf), "--robot-file", str(toml))
    assert r.returncode == 0, r.stderr
    robot, xi = calibrated_model(read_params(p))
    assert not np.allclose(xi, robot.nominal)  # calibrated values, not the nominal
    u = yourdfpy.URDF.load(str(urdf), build_scene_graph=True, load_meshes=False)
    assert [j for j in u.actuated_joint_names] == [f"joint{i}" for i in range(1, 7)]
    rng = np.random.default_rng(0)
    qm = rng.uniform(robot.limits[:, 0], robot.limits[:, 1], size=(25, 6))
    for q in qm:
        u.update_cfg(dict(zip(u.actuated_joint_names, q)))
        T = u.get_transform("tool0", "base_link")
        assert np.abs(T - robot.frames(q, xi)[0]).max() < 1e-9
    back = get_robot(load_robot_file(toml))
    assert back.param_names == robot.param_names and back.fixed == robot.fixed
    assert np.array_equal(back.nominal, xi)
    assert np.abs(back.frames(qm, back.nominal) - robot.frames(qm, xi)).max() < 1e-12


def test_urdf_export_refuses_a_ratio_other_than_one(tmp_path):
    t, p = tmp_path / "t.jsonl", tmp_path / "p.json"
    assert app("trace", "generate", "--robot", os.path.join(ROBOTS, "agebot-sm.toml"),
               "--method", "sm-position", "--out", str(t)).returncode == 0
    assert app("batch", str(t), "--out", str(p)).returncode == 0
    out = tmp_path / "a.urdf"
    r = app("params", "export", str(p), "--urdf", str(out))
    assert r.returncode != 0 and not out.exists()
    assert r.stderr.startswith("error: ") and "joint 1: k1 = " in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1
    r = app("params", "export", os.path.join(TRACES, "..", "..", "README.md"), "--urdf", str(out))
    assert r.returncode != 0 and "Traceback" not in r.stderr


# -- trace import ----------------------------------------------------------------------
def _csv_of(trace_path, csv_path, *, mm_deg: bool):
    """A CSV as a user would have it, from a generated trace (lengths in mm and angles
    in degrees where ``mm_deg``)."""
    tr = read_trace(trace_path)
    n = len(tr.poses[0]["qm"])
    L, A = (1e3, 180 / math.pi) if mm_deg else (1.0, 1.0)
    cols = [f"qm{i}" for i in range(1, n + 1)]
    if tr.method == "sm-full-pose":
        cols += ["x", "y", "z", "roll", "pitch", "yaw"]
    elif tr.method == "sm-distance-tilt":
        cols += ["distance", "tilt_roll", "tilt_pitch"]
    lines = [",".join(cols + ["use"])]
    if tr.reference is not None:
        lines.append(",".join(repr(v) for v in tr.reference["qm"]) + "," * (len(cols) - n)
                     + ",reference")
    for p in tr.poses:
        vals = list(p["qm"])
        if tr.method == "sm-full-pose":
            vals += [v * L for v in p["pose"][:3]] + [v * A for v in p["pose"][3:]]
        elif tr.method == "sm-distance-tilt":
            vals += [p["distance"] * L] + [v * A for v in p["tilt"]]
        lines.append(",".join(repr(v) for v in vals) + ",fit")
    csv_path.write_text("\n".join(lines) + "\n")


@pytest.mark.parametrize("method", ["sm-full-pose", "sm-distance-tilt"])
def test_import_csv_gives_the_same_calibration(tmp_path, method):
    t = tmp_path / "gen.jsonl"
    robot = os.path.join(ROBOTS, "scara-like.toml")
    assert app("trace", "generate", "--robot", robot, "--method", method, "--seed", "3",
               "--out", str(t)).returncode == 0
    csv_path, imp = tmp_path / "meas.csv", tmp_path / "imp.jsonl"
    _csv_of(t, csv_path, mm_deg=True)
    r = app("trace", "import", str(csv_path), "--robot", robot, "--method", method,
            "--length-unit", "mm", "--angle-unit", "deg", "--out", str(imp))
    assert r.returncode == 0, r.stderr
    a, b = calibrate_trace(str(t)), calibrate_trace(str(imp))
    assert np.allclose(a.result.x, b.result.x, rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize("edit,words", [
    (lambda ls: ls[:2] + [ls[2].replace(ls[2].split(",")[1], "abc", 1)] + ls[3:], ":3: column qm2: 'abc'"),
    (lambda ls: [ls[0].replace("yaw", "jaw")] + ls[1:], ":1: column 'jaw'"),
    (lambda ls: ls[:3] + [ls[3] + ",1"] + ls[4:], ":4: a value beyond the 11 columns the "
                                                  "header names (column 12)"),
    (lambda ls: ls[:3] + [ls[3].rsplit(",", 1)[0]] + ls[4:], ":4: 10 values for 11 columns"),
    (lambda ls: ls[:2] + ["999," + ls[2].split(",", 1)[1]] + ls[3:], ":3: column qm1: 999.0 is outside"),
])
def test_import_errors_name_the_csv_line(tmp_path, edit, words):
    t = tmp_path / "gen.jsonl"
    robot = os.path.join(ROBOTS, "scara-like.toml")
    assert app("trace", "generate", "--robot", robot, "--method", "sm-full-pose", "--count", "5",
               "--out", str(t)).returncode == 0
    csv_path = tmp_path / "m.csv"
    _csv_of(t, csv_path, mm_deg=False)
    csv_path.write_text("\n".join(edit(csv_path.read_text().splitlines())) + "\n")
    out = tmp_path / "imp.jsonl"
    r = app("trace", "import", str(csv_path), "--robot", robot, "--method", "sm-full-pose",
            "--out", str(out))
    assert r.returncode != 0 and not out.exists()
    assert len(r.stderr.strip().splitlines()) == 1 and words in r.stderr, r.stderr
