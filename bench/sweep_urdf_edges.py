"""Issue 43's cases for ``bench/sweep_edges.py`` (``--only u43-``): a URDF and a tracker's
CSV as users' files come, each case a subprocess of ``app.py`` judged as the sweep judges
every case (wrong, changed, hang, traceback, messy).

A URDF that is not one (a joint cycle, a joint whose parent is its own child, two joints
or links of one name, two origins, an axis of two numbers, inf or nan, an unexpanded
xacro, an SDF, no robot name, a link with two parents); a CSV with a user's mistakes
(separators, a trailing comma, a decimal comma, a column twice, every row twice, a
held-out file that is the fit file or says ``use=fit`` or is in another unit or frame,
a point seen only held out, one pose); an export over the trace or the robot's own URDF.
"""
from __future__ import annotations

import os
import shutil


def urdf_edge_cases(root: str, d: str, Case) -> list:
    """The cases (``Case`` is the sweep's dataclass)."""
    from pathlib import Path

    from calibration.robots import get_robot       # (this checkout's: the sweep's tools)
    from drivers.urdf_file import load_urdf
    from station.simulation import tracegen_urdf as tg

    top = os.path.join(d, "u43")
    os.makedirs(top, exist_ok=True)
    urdf = os.path.join(top, "arm.urdf")
    shutil.copy(os.path.join(root, "fixtures", "robots", "m10ia-like.urdf"), urdf)
    text = Path(urdf).read_text()
    rob = get_robot(load_urdf(urdf, "base_link", "tool0"))
    tg.tracker_export(Path(top), rob, 43, unseen=0.0)
    csv = os.path.join(top, "meas.csv")
    jmap = os.path.join(top, "map.toml")
    lines = Path(csv).read_text().splitlines()
    head, rows = lines[0].split(","), [ln.split(",") for ln in lines[1:]]
    C = []

    def put(name, content):
        path = os.path.join(top, name)
        Path(path).write_text(content)
        return path

    def rows_csv(name, h, rs, sep=",", end=""):
        return put(name, "\n".join(sep.join(r) + end for r in [h, *rs]) + "\n")

    def urdf_case(name, old, new, expect="refuse"):
        assert old in text, old
        path = put(f"{name}.urdf", text.replace(old, new, 1))
        C.append(Case(f"u43-urdf-{name}", ["trace", "generate", "--robot", path, "--base-link",
                                            "base_link", "--tip-link", "tool0", "--method",
                                            "sm-markers", "--out", os.path.join(top, f"{name}.jsonl")],
                      expect=expect, inputs=[path]))

    urdf_case("cycle", '<parent link="base_link"/>\n    <child link="link_1"/>',
              '<parent link="link_3"/>\n    <child link="link_1"/>')
    urdf_case("own-child", '<parent link="link_1"/>\n    <child link="link_2"/>',
              '<parent link="link_2"/>\n    <child link="link_2"/>')
    urdf_case("two-joints-one-name", '<joint name="joint_5"', '<joint name="joint_4"')
    urdf_case("two-origins", '<origin xyz="0.1805 0.0625 0.2" rpy="0 0 0"/>',
              '<origin xyz="0.1805 0.0625 0.2" rpy="0 0 0"/><origin xyz="0.18 0.06 0.2"/>')
    urdf_case("axis-two-numbers", '<axis xyz="0 1 0"/>', '<axis xyz="0 1"/>')
    urdf_case("rpy-inf", 'xyz="0 -0.0225 0.6" rpy="0 0 0"', 'xyz="0 -0.0225 0.6" rpy="0 0 inf"')
    urdf_case("xyz-nan", 'xyz="0 -0.0225 0.6"', 'xyz="0 nan 0.6"')
    urdf_case("xacro", 'xyz="0 -0.0225 0.6"', 'xyz="0 ${l2} 0.6"')
    urdf_case("no-name", '<robot name="m10ia_like">', "<robot>")
    urdf_case("link-two-parents", '<child link="tool0"/>', '<child link="link_6"/>')
    urdf_case("negative-mass", '<mass value="18.0"/>', '<mass value="-18.0"/>')
    sdf = put("arm.sdf.urdf", '<?xml version="1.0"?>\n<sdf version="1.6"><model name="a"/></sdf>\n')
    C.append(Case("u43-urdf-sdf", ["trace", "generate", "--robot", sdf, "--base-link",
                                   "base_link", "--tip-link", "tool0", "--method", "sm-markers",
                                   "--out", os.path.join(top, "sdf.jsonl")], inputs=[sdf]))

    def imp(name, path, *extra, expect="refuse"):
        out = os.path.join(top, f"{name}.jsonl")
        C.append(Case(f"u43-csv-{name}", ["trace", "import", path, "--robot", urdf,
                                          "--base-link", "base_link", "--tip-link", "tool0",
                                          "--method", "sm-markers", "--length-unit", "mm",
                                          "--angle-unit", "deg", "--joint-map", jmap, "--out",
                                          out, *extra], expect=expect,
                      inputs=[path, urdf] + [e for e in extra if os.path.isfile(str(e))]))

    imp("semicolons", rows_csv("semi.csv", head, rows, sep=";"), expect="ok")
    imp("tabs", rows_csv("tabs.csv", head, rows, sep="\t"), expect="ok")
    imp("trailing-comma", rows_csv("trail.csv", head, rows, end=","), expect="ok")
    comma = [r[:] for r in rows]
    comma[4][head.index("m1_x")] = comma[4][head.index("m1_x")].replace(".", ",")
    imp("decimal-comma", rows_csv("comma.csv", head, comma, sep=";"))
    k = head.index("m2_y")
    imp("x2-and-m2_x", rows_csv("both.csv", head + ["y2"], [r + [r[k]] for r in rows]))
    imp("every-row-twice", rows_csv("twice.csv", head, rows + rows))
    imp("one-pose", rows_csv("one.csv", head, rows[:1]))
    u = head.index("use")
    h = [c for i, c in enumerate(head) if i != u]
    fit = [[c for i, c in enumerate(r) if i != u] for r in rows if r[u] == "fit"]
    held = [[c for i, c in enumerate(r) if i != u] for r in rows if r[u] == "validation"]
    fit_csv = rows_csv("fit.csv", h, fit)
    imp("validation-is-the-fit-file", fit_csv, "--validation", fit_csv)
    imp("validation-says-fit", fit_csv, "--validation",
        rows_csv("said.csv", h + ["use"], [r + ["fit"] for r in held]))
    P = [h.index(f"m{j}_{a}") for j in (1, 2, 3) for a in "xyz"]
    imp("validation-in-m", fit_csv, "--validation", rows_csv("held-m.csv", h, [
        [str(float(v) / 1000) if i in P else v for i, v in enumerate(r)] for r in held]))
    imp("validation-moved-1m", fit_csv, "--validation", rows_csv("held-moved.csv", h, [
        [str(float(v) + 1000) if i in P[::3] else v for i, v in enumerate(r)] for r in held]))
    imp("point-only-held-out", rows_csv("blank.csv", h, [
        [("" if i in P[6:] else v) for i, v in enumerate(r)] for r in fit]), "--validation",
        rows_csv("held.csv", h, held))
    # an export over the trace, the only copy of the measurements; over the robot's URDF
    trace = os.path.join(top, "t.jsonl")
    params = os.path.join(top, "p.json")
    C.append(Case("u43-export-over-the-trace", ["trace", "import", csv, "--robot", urdf,
                                                "--base-link", "base_link", "--tip-link", "tool0",
                                                "--method", "sm-markers", "--length-unit", "mm",
                                                "--angle-unit", "deg", "--joint-map", jmap,
                                                "--out", trace],
                  then=[["batch", trace, "--out", params],
                        ["params", "export", params, "--urdf", trace]],
                  inputs=[csv, urdf], timeout=240.0))
    trace2, params2 = os.path.join(top, "t2.jsonl"), os.path.join(top, "p2.json")
    C.append(Case("u43-export-over-the-robot-s-urdf", [
        "trace", "import", csv, "--robot", urdf, "--base-link", "base_link", "--tip-link",
        "tool0", "--method", "sm-markers", "--length-unit", "mm", "--angle-unit", "deg",
        "--joint-map", jmap, "--out", trace2],
        then=[["batch", trace2, "--out", params2], ["params", "export", params2, "--urdf", urdf]],
        inputs=[csv, urdf], timeout=240.0))
    C += _rail_and_recalibration(top, urdf, text, Case)
    return C


def _rail_and_recalibration(top: str, urdf: str, text: str, Case) -> list:
    """An arm on a rail printed in m beside a tracker's mm (refused, the column named);
    the recalibration from the station's own export of the turned-wrist arm seen at
    0.5 mm (converged, passed)."""
    from pathlib import Path

    from calibration.robots import get_robot
    from drivers.urdf_file import load_urdf
    from station.simulation import tracegen_urdf as tg
    from tests.station.urdf_helpers import rail_export, turned_wrist

    os.makedirs(os.path.join(top, "rail"), exist_ok=True)
    rail_path, rail_csv_path = rail_export(Path(top) / "rail", 43)
    rail, rail_csv = str(rail_path), str(rail_csv_path)
    out = [Case("u43-csv-rail-in-m-read-in-mm", [
        "trace", "import", rail_csv, "--robot", rail, "--base-link", "base_link", "--tip-link",
        "tool0", "--method", "sm-markers", "--length-unit", "mm", "--angle-unit", "deg", "--out",
        os.path.join(top, "rail.jsonl")], inputs=[rail_csv, rail])]
    sub = os.path.join(top, "recal")
    os.makedirs(sub, exist_ok=True)
    arm = os.path.join(sub, "arm.urdf")
    Path(arm).write_text(turned_wrist(text))
    tg.tracker_export(Path(sub), get_robot(load_urdf(urdf, "base_link", "tool0")), 43,
                      noise=5e-4, unseen=0.0)

    def imported(robot, trace):
        return ["trace", "import", os.path.join(sub, "meas.csv"), "--robot", robot,
                "--base-link", "base_link", "--tip-link", "tool0", "--method", "sm-markers",
                "--length-unit", "mm", "--angle-unit", "deg", "--joint-map",
                os.path.join(sub, "map.toml"), "--out", trace]

    t1, p1, cal = (os.path.join(sub, n) for n in ("t1.jsonl", "p1.json", "cal.urdf"))
    t2, p2 = os.path.join(sub, "t2.jsonl"), os.path.join(sub, "p2.json")
    out.append(Case("u43-recalibrate-from-the-export", imported(arm, t1), expect="ok",
                    then=[["batch", t1, "--out", p1], ["params", "export", p1, "--urdf", cal],
                          imported(cal, t2), ["batch", t2, "--out", p2]],
                    inputs=[os.path.join(sub, "meas.csv"), arm], timeout=240.0))
    return out
