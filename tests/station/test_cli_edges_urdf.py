"""Issue 43: the URDF and CSV path, as a user's files come. Each case is the right answer
or one line naming the file, line or column and what to do; nothing an input holds is
overwritten. (The URDF's own checks: tests/drivers/test_urdf_checks.py.)"""
from __future__ import annotations

import hashlib
import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from calibration.robots import get_robot
from drivers.urdf_file import load_urdf
from station.simulation import tracegen_urdf as tg
from tests.station.test_cli_edges import one_line, run

ROOT = Path(__file__).resolve().parents[2]
URDF = ROOT / "fixtures" / "robots" / "m10ia-like.urdf"


@pytest.fixture(scope="module")
def export(tmp_path_factory):
    """A tracker's export of a drawn arm (mm, degrees, the FANUC joint map, 60 fit rows
    and 20 held out): ``(folder, header, rows)``."""
    folder = tmp_path_factory.mktemp("tracker")
    rob = get_robot(load_urdf(URDF, "base_link", "tool0"))
    tg.tracker_export(folder, rob, 11, unseen=0.0)
    lines = (folder / "meas.csv").read_text().splitlines()
    return folder, lines[0].split(","), [ln.split(",") for ln in lines[1:]]


def write(path: Path, head, rows, sep=",", end="") -> Path:
    path.write_text("\n".join(sep.join(r) + end for r in [head, *rows]) + "\n")
    return path


def fit_only(head, rows):
    """The fit rows without the use column, and the held-out ones likewise."""
    u = head.index("use")
    keep = [c for i, c in enumerate(head) if i != u]
    cut = [[c for i, c in enumerate(r) if i != u] for r in rows]
    return keep, [c for c, r in zip(cut, rows) if r[u] == "fit"], \
        [c for c, r in zip(cut, rows) if r[u] == "validation"]


def imp(capsys, folder, csv, *extra):
    return run(capsys, "trace", "import", csv, "--robot", URDF, "--base-link", "base_link",
               "--tip-link", "tool0", "--method", "sm-markers", "--length-unit", "mm",
               "--angle-unit", "deg", "--joint-map", folder / "map.toml", "--out",
               folder / "t.jsonl", *extra)


def poses(folder):
    """The trace's pose records without ``source`` (the file and line: another file's)."""
    return [{k: v for k, v in json.loads(ln).items() if k != "source"}
            for ln in (folder / "t.jsonl").read_text().splitlines()
            if '"record":"pose"' in ln.replace(" ", "")]


@pytest.mark.parametrize("sep, end", [(";", ""), ("\t", ""), (",", ","), (";", ";")])
def test_semicolons_tabs_and_a_trailing_separator_read_as_commas(tmp_path, capsys, export,
                                                                  sep, end):
    folder, head, rows = export
    ref = write(tmp_path / "ref.csv", head, rows)
    assert imp(capsys, folder, ref)[0] == 0
    want = poses(folder)
    got = write(tmp_path / "other.csv", head, rows, sep=sep, end=end)
    rc, _, err = imp(capsys, folder, got)
    assert rc == 0, err
    assert poses(folder) == want


def test_a_decimal_comma_and_an_unnamed_column_are_named(tmp_path, capsys, export):
    folder, head, rows = export
    bad = [r[:] for r in rows]
    bad[3][head.index("m1_x")] = bad[3][head.index("m1_x")].replace(".", ",")
    one_line(*imp(capsys, folder, write(tmp_path / "c.csv", head, bad, sep=";"))[::2],
             "c.csv:5", "column m1_x", "decimal comma")
    head2 = head[:2] + [""] + head[2:]
    rows2 = [r[:2] + ["1"] + r[2:] for r in rows]
    one_line(*imp(capsys, folder, write(tmp_path / "u.csv", head2, rows2))[::2],
             "u.csv:1", "column 3 has no name")
    rows3 = [r + [""] for r in rows]
    rows3[7][-1] = "42"
    one_line(*imp(capsys, folder, write(tmp_path / "v.csv", head, rows3))[::2],
             "v.csv:9", "a value beyond the", "columns the header names")


def test_two_columns_for_one_coordinate_are_named(tmp_path, capsys, export):
    folder, head, rows = export
    k = head.index("m2_y")
    one_line(*imp(capsys, folder, write(tmp_path / "d.csv", head + ["y2"],
                                        [r + [r[k]] for r in rows]))[::2],
             "columns 'm2_y' and 'y2' are both point 2's y")


def test_an_export_written_twice_is_named(tmp_path, capsys, export):
    folder, head, rows = export
    one_line(*imp(capsys, folder, write(tmp_path / "twice.csv", head, rows + rows))[::2],
             f"twice.csv:{len(rows) + 2}: repeats line 2", "written twice")


def test_a_held_out_file_must_be_other_rows_in_the_same_frame_and_unit(tmp_path, capsys,
                                                                       export):
    folder, head, rows = export
    h, fit, held = fit_only(head, rows)
    fit_csv = write(tmp_path / "fit.csv", h, fit)
    # the fit file given again as the held-out one
    one_line(*imp(capsys, folder, fit_csv, "--validation", fit_csv)[::2],
             "a held-out row is a fit row", "--validation")
    # held-out rows that say use=fit
    said = write(tmp_path / "said.csv", h + ["use"], [r + ["fit"] for r in held])
    one_line(*imp(capsys, folder, fit_csv, "--validation", said)[::2],
             "said.csv:2", "column use: 'fit' in the held-out file")
    # held-out rows 1 m away (another frame) or in m where the fit's are in mm
    P = [h.index(f"m{j}_{a}") for j in (1, 2, 3) for a in "xyz"]
    moved = [[str(float(v) + 1000.0) if i in P[::3] else v for i, v in enumerate(r)]
             for r in held]
    one_line(*imp(capsys, folder, fit_csv, "--validation",
                  write(tmp_path / "moved.csv", h, moved))[::2],
             "moved.csv", "held-out rows' points lie", "another instrument frame")
    metres = [[str(float(v) / 1000.0) if i in P else v for i, v in enumerate(r)]
              for r in held]
    one_line(*imp(capsys, folder, fit_csv, "--validation",
                  write(tmp_path / "metres.csv", h, metres))[::2],
             "metres.csv", "another unit")
    # a point seen only in the held-out rows
    blank = [[("" if i in P[6:] else v) for i, v in enumerate(r)] for r in fit]
    one_line(*imp(capsys, folder, write(tmp_path / "blank.csv", h, blank), "--validation",
                  write(tmp_path / "held.csv", h, held))[::2],
             "point 3 is never seen in the fit rows", "held.csv:2")


def test_one_pose_says_how_many_are_needed(tmp_path, capsys, export):
    folder, head, rows = export
    one_line(*imp(capsys, folder, write(tmp_path / "one.csv", head, rows[:1]))[::2],
             "1 fit pose(s)", "at least 3")


def test_joint_values_a_little_beyond_a_limit_are_counted_once(tmp_path, capsys, export):
    """50 rows with joint 1 just past its stop: one warning line with their count (100 000
    rows of an export said 2 703 identical lines)."""
    rob = get_robot(load_urdf(URDF, "base_link", "tool0"))

    def past_the_stop(qm):
        qm[:50, 0] = 3.14 + np.radians(0.2)          # J1 0.2 deg past its +3.14 rad

    tg.tracker_export(tmp_path, rob, 12, unseen=0.0, edit=past_the_stop)
    rc, _, err = imp(capsys, tmp_path, tmp_path / "meas.csv")
    assert rc == 0, err
    lines = [ln for ln in err.splitlines() if ln.startswith("warning:")]
    assert len(lines) == 1 and "joint_1: 50 poses beyond its upper limit" in lines[0], err


def test_params_export_never_replaces_the_trace_or_the_robot_s_own_urdf(tmp_path, capsys,
                                                                        export):
    folder, head, rows = export
    work = tmp_path / "w"
    shutil.copytree(folder, work)
    assert imp(capsys, work, work / "meas.csv")[0] == 0
    params = work / "p.json"
    assert run(capsys, "batch", work / "t.jsonl", "--out", params)[0] == 0
    before = hashlib.sha256((work / "t.jsonl").read_bytes()).hexdigest()
    one_line(*run(capsys, "params", "export", params, "--urdf", work / "t.jsonl")[::2],
             "t.jsonl", "exists and is not a URDF", "it would be lost")
    assert hashlib.sha256((work / "t.jsonl").read_bytes()).hexdigest() == before
    own = shutil.copy(URDF, work / "robot.urdf")
    one_line(*run(capsys, "params", "export", params, "--urdf", own)[::2],
             "robot.urdf", "the robot's own description")
    assert Path(own).read_bytes() == URDF.read_bytes()
    rc, out, err = run(capsys, "params", "export", params, "--urdf", work / "cal.urdf")
    assert rc == 0 and "calibrated URDF written" in out and not err, err
    # a calibrated URDF is replaced by the next one, and a fit kept with
    # --accept-poor-fit says so when it is exported
    assert run(capsys, "batch", work / "t.jsonl", "--out", params, "--accept-poor-fit")[0] == 0
    doc = json.loads(params.read_text())
    assert doc["fit"]["quality"]["passed"]
    rc, out, err = run(capsys, "params", "export", params, "--urdf", work / "cal.urdf")
    assert rc == 0 and not err


def test_an_exported_poor_fit_says_so(tmp_path, capsys, export):
    """A held-out file 5 mm off the rest (refused by the gate) kept with --accept-poor-fit:
    its export says on stderr that the fit failed the gate."""
    folder, head, rows = export
    work = tmp_path / "w"
    shutil.copytree(folder, work)
    u, x1 = head.index("use"), head.index("m1_x")
    off = [[(str(float(v) + 5.0) if i == x1 and r[u] == "validation" and k % 2 else v)
            for i, v in enumerate(r)] for k, r in enumerate(rows)]
    assert imp(capsys, work, write(work / "off.csv", head, off))[0] == 0
    rc, out, _ = run(capsys, "batch", work / "t.jsonl", "--out", work / "p.json",
                     "--accept-poor-fit")
    assert rc == 0 and "fit quality: FAILED, accepted" in out, out
    rc, out, err = run(capsys, "params", "export", work / "p.json", "--urdf", work / "c.urdf")
    assert rc == 0 and err.startswith("warning: this calibration failed the fit-quality gate")


def test_a_point_on_another_link_is_named_whatever_the_noise(tmp_path, capsys):
    """Reflector 3 fixed on link 5 instead of the tool: least squares spread its misfit
    over every point and the gate passed without a stated noise (29.6 mm RMS). Judged
    against the fit without it, it is named and the fit refused."""
    rob = get_robot(load_urdf(URDF, "base_link", "tool0"))
    x, qm, P = tg.tracker_export(tmp_path, rob, 7, unseen=0.0)
    u = x[rob.n_params:].reshape(-1, 3)
    q5 = qm.copy()
    q5[:, 5] = 0.0                                   # joint 6 does not move it
    P[:, 2] = tg.readings(rob, x[:rob.n_params], u[2:3], q5, np.random.default_rng(1),
                          3e-5)[:, 0]
    tg.tracker_export(tmp_path, rob, 7, unseen=0.0, readings_override=P)
    assert imp(capsys, tmp_path, tmp_path / "meas.csv")[0] == 0
    line = one_line(*run(capsys, "batch", tmp_path / "t.jsonl", "--out",
                         tmp_path / "p.json")[::2],
                    "points: point 3 does not move with the tool", "another link")
    assert "outliers" not in line and not (tmp_path / "p.json").exists()


def test_a_session_does_not_resume_a_generated_or_imported_trace(tmp_path, capsys):
    folder = tmp_path / "run"
    folder.mkdir()
    assert run(capsys, "trace", "generate", "--method", "sm-distance-tilt", "--out",
               folder / "trace.jsonl")[0] == 0
    before = (folder / "trace.jsonl").read_bytes()
    from drivers.config import load_station_config
    from station.session.session import Session
    from calibration.errors import ConfigError

    cfg = load_station_config(ROOT / "fixtures" / "stations" / "sim-sm.toml")
    with pytest.raises(ConfigError, match="written by `app.py trace generate`, not recorded "
                                          "by a station session"):
        Session(cfg, "sm-distance-tilt", folder)
    assert (folder / "trace.jsonl").read_bytes() == before


def test_a_rail_in_metres_beside_a_tracker_in_mm_is_named(tmp_path, capsys):
    """An arm on a linear rail (a prismatic first joint), its controller printing the rail
    in m and the joints in degrees beside the tracker's mm: ``--length-unit mm`` applies to
    the rail too, which then moves by a thousandth of its travel. Refused with the column
    and the joint map line that reads it; with that line, the import and the fit pass."""
    from tests.station.urdf_helpers import rail_export

    urdf, csv = rail_export(tmp_path, 7)
    args = ["trace", "import", csv, "--robot", urdf, "--base-link", "base_link", "--tip-link",
            "tool0", "--method", "sm-markers", "--length-unit", "mm", "--angle-unit", "deg",
            "--out", tmp_path / "t.jsonl"]
    line = one_line(*run(capsys, *args)[::2], "meas.csv", "column rail", "prismatic",
                    "metres", "scale = 1000", "--joint-map")
    assert "1 %" not in line  # (the travel it moves: a thousandth)
    (tmp_path / "map.toml").write_text('format = "calstation-joint-map"\nversion = 1\n\n'
                                       '[[joint]]\nurdf = "rail"\ncolumn = "rail"\n'
                                       'scale = 1000.0\n')
    rc, out, err = run(capsys, *args, "--joint-map", tmp_path / "map.toml")
    assert rc == 0, err
    rc, out, err = run(capsys, "batch", tmp_path / "t.jsonl", "--out", tmp_path / "p.json")
    assert rc == 0 and "fit quality: passed" in out, err + out


def test_a_pose_is_named_with_its_file_and_line(tmp_path, capsys, export):
    """Issue 42 item 5: pose indices run on across the fit and held-out files; every pose
    the gate names also carries the file and line a user finds it at."""
    from station.recording.trace import read_trace

    folder, head, rows = export
    shutil.copy(folder / "map.toml", tmp_path / "map.toml")
    rc, out, err = imp(capsys, tmp_path, write(tmp_path / "meas.csv", head, rows))
    assert rc == 0, err
    tr = read_trace(str(tmp_path / "t.jsonl"))
    src = [p["source"] for p in tr.poses]
    assert src[0] == "meas.csv:2" and src[-1] == f"meas.csv:{len(src) + 1}"
    rc, out, err = run(capsys, "batch", tmp_path / "t.jsonl", "--out", tmp_path / "p.json")
    assert rc == 0, err
    import re

    named = re.findall(r"pose \d+ \(meas\.csv:(\d+)\)", out)
    assert named, out
    for line in named:            # the line holds the pose the message names
        pose = next(p for p in tr.poses if p["source"] == f"meas.csv:{line}")
        assert f"pose {pose['index']} (meas.csv:{line})" in out
