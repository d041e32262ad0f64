"""``app.py compensate`` (docs/compensation.md): a program of nominal joint values
rewritten so that the calibrated robot reaches the nominal targets. Simulated robots
(a drawn robot-file arm, a drawn URDF arm seen by a tracker through a FANUC joint map,
AGEBOT's arm and wrist), calibrated; the TRUE robot driven by the compensated program
reaches the nominal targets at least 20 times closer than driven by the nominal one,
and within the calibration's predicted error; a target out of reach is named; a bad
program is refused in one line."""
from __future__ import annotations

import csv
import json
import re

import numpy as np
import pytest

from calibration.compensation import rigid_fit, rotation_error
from calibration.errors import UnreachablePose
from drivers.robot_file import load_robot_file
from drivers.sim.truth import draw_truth
from station.fitting.batch import calibrate_trace
from station.outputs.compensate import setup
from station.outputs.params_file import read_params, write_params
from station.simulation import tracegen_urdf as tg
from tests.station.urdf_helpers import ROOT, URDF, arm
from tests.station.cli_helpers import run, refused

HAYATI = ROOT / "fixtures" / "robots" / "ur5-like-hayati.toml"


def write_program(path, columns: dict, extra: dict | None = None):
    """A program CSV: ``columns`` name -> values (written as given), ``extra`` passed through."""
    extra = extra or {}
    names = list(extra) + list(columns)
    m = len(next(iter(columns.values())))
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(names)
        for k in range(m):
            w.writerow([extra[c][k] for c in extra] + [repr(float(columns[c][k])) for c in columns])


def read_out(path):
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def predicted_mm(out: str) -> float:
    return float(re.search(r"predicted remaining error: ([\d.e+-]+) mm RMS", out).group(1))


def rms(v) -> float:
    return float(np.sqrt(np.mean(np.square(v))))


# -- a robot file's arm ---------------------------------------------------------------------
def _robot_file_case(tmp_path, method: str, seed: int, **spread):
    from calibration.robots import get_robot
    from station.simulation.tracegen_serial import generate_trace

    spec = load_robot_file(HAYATI)
    rob = get_robot(spec)
    xt = draw_truth(spec, np.random.default_rng(seed), **spread).xi()
    generate_trace(tmp_path / "t.jsonl", rob, method, xt, seed=seed,
                   noise={"position": 3e-5, "pose": [3e-5] * 3 + [3e-5] * 3})
    calibrate_trace(str(tmp_path / "t.jsonl"), out=str(tmp_path / "p.json"))
    return rob, xt


@pytest.mark.parametrize("method, spread", [("sm-position", {}),
                                            ("sm-full-pose", {"length": 0.005,
                                                              "offset": 0.003})])
def test_a_robot_file_arm_reaches_the_nominal_targets(tmp_path, capsys, method, spread):
    rob, xt = _robot_file_case(tmp_path, method, 3, **spread)
    lo, hi = rob.limits.T
    q = np.random.default_rng(1).uniform(lo + 0.2 * (hi - lo), hi - 0.2 * (hi - lo), (30, 6))
    write_program(tmp_path / "in.csv", {f"qm{i}": q[:, i - 1] for i in range(1, 7)},
                  {"line": list(range(1, 31)), "speed": ["100"] * 30})
    rc, out, err = run(capsys, "compensate", tmp_path / "p.json", "--program",
                       tmp_path / "in.csv", "--out", tmp_path / "out.csv")
    assert rc == 0, err
    rows = read_out(tmp_path / "out.csv")
    full = method == "sm-full-pose"
    assert list(rows[0]) == (["line", "speed"] + [f"qm{i}" for i in range(1, 7)] + ["residual_mm"]
                             + (["residual_deg"] if full else []) + ["status"])
    assert [r["line"] for r in rows] == [str(k) for k in range(1, 31)]
    ok = np.array([r["status"] == "ok" for r in rows])
    assert ok.sum() >= 28, [r["status"] for r in rows]
    qc = np.array([[float(r[f"qm{i}"]) for i in range(1, 7)] for r in rows])
    nominal = read_params(tmp_path / "p.json")
    x_nom = rob.params({k: p["nominal"] for k, p in nominal["parameters"].items()})
    target = rob.frames(q, x_nom)
    before = np.linalg.norm(rob.frames(q, xt)[:, :3, 3] - target[:, :3, 3], axis=1)[ok]
    after = np.linalg.norm(rob.frames(qc, xt)[:, :3, 3] - target[:, :3, 3], axis=1)[ok]
    factor = rms(before) / rms(after)
    print(f"robot file {method}: nominal program {rms(before) * 1e3:.3g} mm RMS, compensated "
          f"{rms(after) * 1e3:.3g} mm (improved {factor:.0f} times; predicted "
          f"{predicted_mm(out):.3g} mm)")
    assert factor >= 20
    assert rms(after) * 1e3 <= 2.0 * predicted_mm(out)
    if full:
        Rt, Rc = target[ok, :3, :3], rob.frames(qc, xt)[ok, :3, :3]
        turn = [np.linalg.norm(rotation_error(a, b)) for a, b in zip(Rt, Rc)]
        assert np.degrees(rms(turn)) < 0.01


def test_a_program_s_mistakes_are_one_line_naming_the_file_and_line(tmp_path, capsys):
    _robot_file_case(tmp_path, "sm-position", 4)
    q = np.zeros((3, 6)) + 0.3
    base = {f"qm{i}": q[:, i - 1] for i in range(1, 7)}
    cmd = ["compensate", tmp_path / "p.json", "--program", tmp_path / "in.csv", "--out",
           tmp_path / "out.csv"]
    write_program(tmp_path / "in.csv", {**base, "qm7": q[:, 0]})
    refused(capsys, cmd, "in.csv:1", "column 'qm7': not a movable joint of the robot")
    write_program(tmp_path / "in.csv", {k: v for k, v in base.items() if k != "qm4"})
    refused(capsys, cmd, "in.csv:1", "missing the column of joint qm4")
    (tmp_path / "in.csv").write_text("qm1,qm2,qm3,qm4,qm5,qm6\n0,0,0,0,0,0\n0,abc,0,0,0,0\n")
    refused(capsys, cmd, "in.csv:3", "column qm2", "'abc' is not a number")
    (tmp_path / "in.csv").write_text("qm1,qm2,qm3,qm4,qm5,qm6\n0,0,0,0,0,0\n0,0,57.3,0,0,0\n")
    refused(capsys, cmd, "in.csv:3", "column qm3", "far outside the joint's limits")
    (tmp_path / "in.csv").write_text("qm1,qm2,qm3,qm4,qm5,qm6\n0.2,0,3.2,0,0,0\n")
    rc, _out, err = run(capsys, *cmd)           # a little beyond: a warning, kept
    assert rc == 0 and "warning: qm3: 1 row(s) beyond its upper limit 3.1" in err, err
    assert read_out(tmp_path / "out.csv")[0]["status"] == "ok"   # within the limits
    assert "--angle-unit" in refused(capsys, cmd + ["--angle-unit", "deg"], "actuator units")
    doc = json.loads((tmp_path / "p.json").read_text())
    doc["parameters"]["a2"]["value"] += 1e-4
    (tmp_path / "p.json").write_text(json.dumps(doc))
    refused(capsys, cmd, "p.json", "checksum does not match")


# -- a URDF arm seen by a tracker, its controller's columns through a joint map --------------
@pytest.fixture(scope="module")
def urdf_case(tmp_path_factory):
    from station.recording.import_markers import import_markers
    from station.recording.trace_writer import write_trace

    tmp = tmp_path_factory.mktemp("urdf")
    rob = arm()
    x, _qm, _P = tg.tracker_export(tmp, rob, 7101)
    got = import_markers(tmp / "meas.csv", URDF, base_link="base_link", tip_link="tool0",
                         length_unit="mm", angle_unit="deg", joint_map=tmp / "map.toml")
    write_trace(tmp / "t.jsonl", got.header, None, got.poses)
    calibrate_trace(str(tmp / "t.jsonl"), out=str(tmp / "p.json"))
    return tmp, rob, x


def _fanuc_columns(q):
    """The controller's columns of URDF joint values ``q (m, 6)`` rad: degrees, J3 from
    the horizontal (tracegen_urdf.FANUC_MAP)."""
    d = np.degrees(q)
    return {"J1": d[:, 0], "J2": d[:, 1], "J3": d[:, 2] - d[:, 1], "J4": d[:, 3],
            "J5": d[:, 4], "J6": d[:, 5]}


def _urdf_joints(rows):
    J = np.array([[float(r[f"J{i}"]) for i in range(1, 7)] for r in rows])
    return np.radians(np.column_stack([J[:, 0], J[:, 1], J[:, 1] + J[:, 2], J[:, 3:]]))


def test_a_urdf_arm_reaches_the_nominal_targets_through_its_joint_map(urdf_case, tmp_path,
                                                                        capsys):
    """The targets and the true robot in the calibrated base link's frame (the instrument's
    frame seen by the calibration): the true tool (its points' centre, and its turn) at
    the compensated values against the nominal model's."""
    folder, rob, x = urdf_case
    q = tg.draw_poses(rob, 40, np.random.default_rng(4), margin=0.15)
    write_program(tmp_path / "in.csv", _fanuc_columns(q),
                  {"N": [str(10 + k) for k in range(40)], "speed": ["50%"] * 40})
    rc, out, err = run(capsys, "compensate", folder / "p.json", "--program", tmp_path / "in.csv",
                       "--out", tmp_path / "out.csv", "--angle-unit", "deg", "--joint-map",
                       folder / "map.toml")
    assert rc == 0, err
    assert "the tool's point (the centre of its 3 points) and orientation" in out, out
    rows = read_out(tmp_path / "out.csv")
    assert list(rows[0]) == ["N", "speed", "J1", "J2", "J3", "J4", "J5", "J6", "residual_mm",
                             "residual_deg", "status"]
    assert [r["N"] for r in rows] == [str(10 + k) for k in range(40)]
    assert all(r["speed"] == "50%" for r in rows)
    ok = np.array([r["status"] == "ok" for r in rows])
    assert ok.sum() >= 34, [r["status"] for r in rows]
    for r, good in zip(rows, ok):           # an unreachable row keeps its values, named
        assert good or r["status"].startswith("unreachable: ")
    qc = _urdf_joints(rows)
    s = setup(read_params(folder / "p.json"), "p.json")
    for k in np.flatnonzero(ok)[:5]:        # the joint map written back: the solver's values
        np.testing.assert_allclose(qc[k], s.comp.solve(q[k], s.comp.targets(q[k:k + 1])[0]).qm,
                                   atol=1e-9)
    (pb, ab), (pa, aa) = urdf_errors(folder / "p.json", rob, x, q, qc, ok)
    factor = rms(pb) / rms(pa)
    print(f"URDF arm: nominal program {rms(pb) * 1e3:.3g} mm, {np.degrees(rms(ab)):.3g} deg RMS; "
          f"compensated {rms(pa) * 1e3:.3g} mm, {np.degrees(rms(aa)):.2g} deg (position "
          f"improved {factor:.0f} times, orientation {rms(ab) / rms(aa):.0f}; predicted "
          f"{predicted_mm(out):.3g} mm)")
    assert factor >= 20 and rms(ab) / rms(aa) >= 20
    assert rms(pa) * 1e3 <= 2.0 * predicted_mm(out)


def urdf_errors(params, rob, x, q, qc, ok):
    """``((position, angle) nominal, (position, angle) compensated)`` of the TRUE robot
    ``x`` (its parameters with the instrument's frame, then its points on the tool) at the
    rows ``ok`` of the nominal values ``q`` and the compensated ``qc``: its tool (the
    points' centre, its turn) seen in the calibrated base link's frame (the instrument's
    frame as the calibration places it) against the nominal model's targets."""
    n = rob.n_params
    doc = json.loads(params.read_text())
    s = setup(read_params(params), str(params))
    cal = rob.params({k: p["value"] for k, p in doc["parameters"].items() if k in rob.param_names})
    M = (len(x) - n) // 3
    u_nom = np.array([[doc["parameters"][f"marker{j}_{a}"]["nominal"] for a in "xyz"]
                      for j in range(1, M + 1)])
    seen = np.linalg.inv(rob.frame_matrix(cal))          # instrument -> calibrated base link
    body = rigid_fit(u_nom, x[n:].reshape(-1, 3)) @ s.comp.tool_nom   # the true tool
    target = s.comp.targets(q)[ok]
    out = []
    for qq in (q, qc):
        T = (seen @ rob.frames(qq, x[:n]) @ body)[ok]
        out.append((np.linalg.norm(T[:, :3, 3] - target[:, :3, 3], axis=1),
                    np.array([np.linalg.norm(rotation_error(a, b))
                              for a, b in zip(target[:, :3, :3], T[:, :3, :3])])))
    return out


def test_a_target_out_of_reach_within_the_limits_is_named(urdf_case, tmp_path, capsys):
    """A row with a joint at its limit where the compensation would take it beyond: kept
    as it was, its status and a warning name the row and the joint."""
    folder, rob, _x = urdf_case
    s = setup(read_params(folder / "p.json"), "p.json")
    q0 = tg.draw_poses(rob, 1, np.random.default_rng(8), margin=0.25)[0]
    found = None
    for i in range(6):
        for side in (0, 1):
            q = q0.copy()
            q[i] = rob.limits[i, side]
            sol = s.comp.solve(q, s.comp.targets(q[None])[0])
            if sol.joint == i:
                found = (q, i, ("lower", "upper")[side])
                break
        if found:
            break
    assert found, "no joint of the drawn row is pushed past its limit"
    q, i, side = found
    prog = np.vstack([q0, q, q0])
    write_program(tmp_path / "in.csv", _fanuc_columns(prog))
    rc, out, err = run(capsys, "compensate", folder / "p.json", "--program", tmp_path / "in.csv",
                       "--out", tmp_path / "out.csv", "--angle-unit", "deg", "--joint-map",
                       folder / "map.toml")
    assert rc == 0, err
    rows = read_out(tmp_path / "out.csv")
    assert [r["status"] == "ok" for r in rows] == [True, False, True]
    name = rob.spec.joint_names[i]
    assert rows[1]["status"].startswith(f"unreachable: {name} would pass its {side} limit")
    assert f"in.csv:3 (row 2): unreachable: {name}" in err, err
    assert "(3 rows: 2 compensated, 1 unreachable)" in out
    before = _fanuc_columns(prog[1:2])
    for c, v in before.items():              # never clipped: the row as it came
        assert float(rows[1][c]) == pytest.approx(v[0], abs=1e-9)


def test_a_urdf_program_s_column_mistakes(urdf_case, tmp_path, capsys):
    folder, rob, _x = urdf_case
    q = tg.draw_poses(rob, 2, np.random.default_rng(2))
    cmd = ["compensate", folder / "p.json", "--program", tmp_path / "in.csv", "--out",
           tmp_path / "out.csv", "--angle-unit", "deg", "--joint-map", folder / "map.toml"]
    write_program(tmp_path / "in.csv", {**_fanuc_columns(q), "joint_3": q[:, 2]})
    refused(capsys, cmd, "column 'joint_3': the joint map gives joint_3 from its columns J2, J3")
    write_program(tmp_path / "in.csv", {f"joint_{i}": np.degrees(q[:, i - 1])
                                        for i in range(1, 7)})
    refused(capsys, cmd[:-4], "far outside", "--angle-unit deg")   # degrees read as rad
    write_program(tmp_path / "in.csv", {**{f"joint_{i}": q[:, i - 1] for i in range(1, 7)},
                                        "world_to_base": q[:, 0]})
    refused(capsys, cmd[:-4], "column 'world_to_base': not a movable joint of the robot")


# -- AGEBOT ---------------------------------------------------------------------------------
def test_agebot_s_arm_reaches_the_nominal_targets(tmp_path, capsys):
    from calibration import planning
    from calibration.robots import get_robot
    from station.simulation.tracegen import generate_trace

    rob = get_robot("agebot-sm")
    xt = draw_truth("agebot-sm", np.random.default_rng(5)).xi()
    generate_trace(tmp_path / "t.jsonl", "sm-distance-tilt", xt, seed=5,
                   noise={"distance": 1e-5, "tilt": 1e-4})
    calibrate_trace(str(tmp_path / "t.jsonl"), out=str(tmp_path / "p.json"))
    s = setup(read_params(tmp_path / "p.json"), "p.json")
    rng = np.random.default_rng(2)
    box = planning.box_array(rob, planning.SM_BOX_7_1, np.r_[rob.base_offset(s.comp.xi_nom), 0])
    q = []
    while len(q) < 20:                       # a program planned with the nominal model
        try:
            q.append(rob.ik(rng.uniform(box[:, 0], box[:, 1]), s.comp.xi_nom))
        except UnreachablePose:
            continue
    q = np.array(q)
    write_program(tmp_path / "in.csv", {f"qm{i}": q[:, i - 1] for i in range(1, 5)})
    rc, out, err = run(capsys, "compensate", tmp_path / "p.json", "--program",
                       tmp_path / "in.csv", "--out", tmp_path / "out.csv")
    assert rc == 0, err
    assert "in the rail's frame" in out
    rows = read_out(tmp_path / "out.csv")
    assert list(rows[0]) == ["qm1", "qm2", "qm3", "qm4", "residual_mm", "residual_deg", "status"]
    assert all(r["status"] == "ok" for r in rows)
    qc = np.array([[float(r[f"qm{i}"]) for i in range(1, 5)] for r in rows])
    x = xt.copy()
    for nm in ("theta0", "a0", "q1_off"):    # the rail's frame (the method's is its own)
        x[rob.index(nm)] = 0.0
    target = s.comp.targets(q)
    before = np.linalg.norm(rob.fk(q, x)[:, :3] - target[:, :3], axis=1)
    after = np.linalg.norm(rob.fk(qc, x)[:, :3] - target[:, :3], axis=1)
    print(f"AGEBOT arm (sm-distance-tilt): nominal program {rms(before) * 1e3:.4g} mm, "
          f"compensated {rms(after) * 1e3:.3g} mm (improved {rms(before) / rms(after):.0f} "
          f"times; predicted {predicted_mm(out):.3g} mm)")
    assert rms(before) / rms(after) >= 20 and rms(after) * 1e3 <= 2.0 * predicted_mm(out)


def test_agebot_s_wrist_reaches_the_nominal_orientations(tmp_path, capsys):
    """The wrist's targets are orientations (no residual_mm). Its parameter file's nominal is
    the station's start estimate, close to the truth: made a wrist off by a few per cent
    (the file rewritten with its checksum) so that there is something to compensate."""
    from calibration.robots import get_robot
    from calibration.robots.agebot_pm import rot_xyz
    from station.simulation.tracegen import generate_trace

    rob = get_robot("agebot-pm")
    xt = draw_truth("agebot-pm", np.random.default_rng(5)).xi()
    generate_trace(tmp_path / "t.jsonl", "pm-fk", xt, seed=5, noise={"orientation": 1e-4})
    calibrate_trace(str(tmp_path / "t.jsonl"), out=str(tmp_path / "p.json"))
    doc = json.loads((tmp_path / "p.json").read_text())
    for name, p in doc["parameters"].items():
        if p["identifiable"]:
            p["nominal"] = p["value"] * (1.03 if name[0] in "kal" else 1.0) + (
                0.002 if name.endswith("_off") else 0.0)
    del doc["checksum"]
    write_params(tmp_path / "p.json", doc)
    s = setup(read_params(tmp_path / "p.json"), "p.json")
    X = np.random.default_rng(3).uniform(-0.2, 0.2, (15, 3))
    q = np.array([rob.ik(v, s.comp.xi_nom) for v in X])
    write_program(tmp_path / "in.csv", {f"qm{i}": q[:, i - 1] for i in range(1, 4)})
    rc, out, err = run(capsys, "compensate", tmp_path / "p.json", "--program",
                       tmp_path / "in.csv", "--out", tmp_path / "out.csv")
    assert rc == 0, err
    rows = read_out(tmp_path / "out.csv")
    assert list(rows[0]) == ["qm1", "qm2", "qm3", "residual_deg", "status"]
    assert all(r["status"] == "ok" for r in rows), [r["status"] for r in rows]
    qc = np.array([[float(r[f"qm{i}"]) for i in range(1, 4)] for r in rows])

    def turn(qq):
        Xt = rob.fk(qq, xt, guess=X)
        return np.array([np.linalg.norm(rotation_error(rot_xyz(a)[0], rot_xyz(b)[0]))
                         for a, b in zip(X, Xt)])

    before, after = turn(q), turn(qc)
    pred = float(re.search(r"predicted remaining error: ([\d.e+-]+) deg RMS", out).group(1))
    print(f"AGEBOT wrist (pm-fk): nominal program {np.degrees(rms(before)):.3g} deg, compensated "
          f"{np.degrees(rms(after)):.2g} deg (improved {rms(before) / rms(after):.0f} times; "
          f"predicted {pred:.2g} deg)")
    assert rms(before) / rms(after) >= 20 and np.degrees(rms(after)) <= 2.0 * pred


# -- what issue 45 asks: ten drawn arms of each kind ------------------------------------------
def test_ten_drawn_urdf_arms_and_ten_robot_file_arms(tmp_path, capsys):
    """Ten URDF arms seen by a tracker (tracegen_urdf.tracker_export: origins ~1 mm / 1
    mrad off, zeros 5 mrad, 30 um noise, three reflectors) and ten robot-file arms
    (ur5-like-hayati drawn as truth draw draws them, sm-position, 30 um): on each, the
    true robot driven by the compensated program reaches the nominal targets at least 20
    times closer (position RMS) than driven by the nominal program, and within twice the
    calibration's predicted error."""
    from station.recording.import_markers import import_markers
    from station.recording.trace_writer import write_trace

    rob, factors = arm(), {"URDF": [], "robot file": []}
    for seed in range(7110, 7120):
        folder = tmp_path / f"u{seed}"
        folder.mkdir()
        x, _qm, _P = tg.tracker_export(folder, rob, seed)
        got = import_markers(folder / "meas.csv", URDF, base_link="base_link", tip_link="tool0",
                             length_unit="mm", angle_unit="deg", joint_map=folder / "map.toml")
        write_trace(folder / "t.jsonl", got.header, None, got.poses)
        calibrate_trace(str(folder / "t.jsonl"), out=str(folder / "p.json"))
        q = tg.draw_poses(rob, 30, np.random.default_rng(seed), margin=0.15)
        write_program(folder / "in.csv", _fanuc_columns(q))
        rc, out, err = run(capsys, "compensate", folder / "p.json", "--program",
                           folder / "in.csv", "--out", folder / "out.csv", "--angle-unit", "deg",
                           "--joint-map", folder / "map.toml")
        assert rc == 0, err
        rows = read_out(folder / "out.csv")
        ok = np.array([r["status"] == "ok" for r in rows])
        assert ok.sum() >= 24, seed
        (pb, _ab), (pa, _aa) = urdf_errors(folder / "p.json", rob, x, q, _urdf_joints(rows), ok)
        factors["URDF"].append((rms(pb) / rms(pa), rms(pa) * 1e3 / predicted_mm(out)))
    for seed in range(20, 30):
        folder = tmp_path / f"r{seed}"
        folder.mkdir()
        rf, xt = _robot_file_case(folder, "sm-position", seed)
        lo, hi = rf.limits.T
        q = np.random.default_rng(seed).uniform(lo + 0.2 * (hi - lo), hi - 0.2 * (hi - lo),
                                                (30, 6))
        write_program(folder / "in.csv", {f"qm{i}": q[:, i - 1] for i in range(1, 7)})
        rc, out, err = run(capsys, "compensate", folder / "p.json", "--program",
                           folder / "in.csv", "--out", folder / "out.csv")
        assert rc == 0, err
        rows = read_out(folder / "out.csv")
        ok = np.array([r["status"] == "ok" for r in rows])
        assert ok.sum() >= 27, seed
        qc = np.array([[float(r[f"qm{i}"]) for i in range(1, 7)] for r in rows])
        doc = read_params(folder / "p.json")
        target = rf.frames(q, rf.params({k: p["nominal"] for k, p in doc["parameters"].items()}))
        before = np.linalg.norm(rf.frames(q, xt)[:, :3, 3] - target[:, :3, 3], axis=1)[ok]
        after = np.linalg.norm(rf.frames(qc, xt)[:, :3, 3] - target[:, :3, 3], axis=1)[ok]
        factors["robot file"].append((rms(before) / rms(after),
                                      rms(after) * 1e3 / predicted_mm(out)))
    for kind, got in factors.items():
        f, r = np.array(got).T
        print(f"{kind} arms: improved {f.min():.0f} to {f.max():.0f} times (median "
              f"{np.median(f):.0f}); compensated RMS / predicted {r.min():.2f} to {r.max():.2f}")
        assert f.min() >= 20 and r.max() <= 2.0, got
