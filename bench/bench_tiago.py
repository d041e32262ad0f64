"""The TIAGo worked example on FIGAROH's public motion-capture data, beside FIGAROH's own
figures (docs/urdf-robots.md, "A worked example: TIAGo").

The data are not in this repository (they are FIGAROH's, Apache-2.0, (c) Thanh Nguyen,
CNRS, Toward SAS; the robot's URDF is PAL Robotics' TIAGo description as FIGAROH
ships it): download them as docs/urdf-robots.md says into a folder and give it:

    python bench/bench_tiago.py --data ~/tiago-data

FIGAROH's held-out protocol: fit the 37 postures of 2021-11-30, hold out the 62 of
2021-11-26 (the same Qualisys base frame), chain base_footprint -> wrist_ft_tool_link.
Each calibration runs the station's own path (trace import of the CSV as it comes,
then batch with the fit-quality gate) and prints the fit's and the held-out poses' 3D
RMS of the markers in mm:

* joint offsets only (``batch --hold 'j*'``), marker 1: FIGAROH's reference level
  (its ``joint_offset``: 2.88 mm fit, 4.23 mm held out, 12.0 mm max);
* the full geometric model, marker 1 (FIGAROH's ``full_params``: 3.07 mm held out);
* the full model from all four points of the hand's rigid body;
* the same four-point data turned by an arbitrary rotation: the calibrated robot must
  be the same to 1e-6 relative and the held-out error the same;
* the export into TIAGo's own URDF: every link and joint name kept, its forward
  kinematics (yourdfpy) equal to the parameter file's.
"""
from __future__ import annotations

import argparse
import csv
import hashlib
import io
import json
import math
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

FILES = {"qualisys_2021-11-30_static_postures.csv":
         "b6c0051e20c6a077a6d2cf64ba912996945bbb85d6860cd6cea7d8ff65b1b9af",
         "qualisys_2021-11-26_static_postures.csv":
         "7c986df711757c4d31d8bb6db34b354f72318a78673dac280fd3a14abc5460a0",
         "tiago_48_schunk.urdf": None}
IGNORE = "shipped_row,t_start_robot,t_end_robot,marker_std_mm"
FIGAROH = {"offsets": (2.88, 4.23, 12.0), "full": (None, 3.07, None)}


def app(*args) -> tuple[int, str]:
    import contextlib

    import app as app_module

    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        rc = app_module.main([str(a) for a in args])
    return rc, out.getvalue() + err.getvalue()


def keep_points(src: Path, dst: Path, points, turn=None) -> None:
    """``src`` with only these points' columns (x1..z4), optionally turned."""
    rows = list(csv.reader(src.open()))
    head = rows[0]
    cols = {c: i for i, c in enumerate(head)}
    drop = {cols[f"{a}{j}"] for j in range(1, 5) if j not in points for a in "xyz"}
    with dst.open("w", newline="") as f:
        w = csv.writer(f, lineterminator="\n")
        for k, r in enumerate(rows):
            if k and turn is not None:
                for j in points:
                    idx = [cols[f"{a}{j}"] for a in "xyz"]
                    p = turn @ np.array([float(r[i]) for i in idx]) + np.array([0.5, -1.0, 2.0])
                    for i, v in zip(idx, p):
                        r[i] = repr(float(v))
            w.writerow([v for i, v in enumerate(r) if i not in drop])


def calibrate(tmp: Path, data: Path, points, hold=None, turn=None, tag="", extra=()):
    fit, val = tmp / f"fit{tag}.csv", tmp / f"val{tag}.csv"
    keep_points(data / "qualisys_2021-11-30_static_postures.csv", fit, points, turn)
    keep_points(data / "qualisys_2021-11-26_static_postures.csv", val, points, turn)
    trace, params = tmp / f"t{tag}.jsonl", tmp / f"p{tag}.json"
    rc, text = app("trace", "import", fit, "--validation", val, "--robot",
                   data / "tiago_48_schunk.urdf", "--base-link", "base_footprint", "--tip-link",
                   "wrist_ft_tool_link", "--method", "sm-markers", "--ignore-columns", IGNORE,
                   "--out", trace)
    assert rc == 0, text
    args = ["batch", trace, "--out", params] + (["--hold", hold] if hold else []) + list(extra)
    rc, text = app(*args)
    assert rc == 0, text
    doc = json.loads(params.read_text())
    return doc, text, params


def figures(doc, text):
    """``(fit RMS, held-out RMS, held-out max, identifiable)``, mm, from the parameter file."""
    pts = next(c["points"] for c in doc["fit"]["quality"]["checks"] if "points" in c)
    return (doc["fit_points"]["rms"] * 1e3, pts["rms_after"] * 1e3, pts["max_after"] * 1e3,
            doc["fit"]["identifiable_count"])


def marker_one_heldout(params: Path) -> float:
    """The held-out 3D RMS of point 1 alone (FIGAROH fits and scores marker 1)."""
    from calibration.methods import build
    from station.outputs.export import calibrated_model
    from station.recording.trace import read_trace

    doc = json.loads(params.read_text())
    trace = read_trace(str(params.with_name(params.name.replace("p", "t", 1).replace(".json",
                                                                                      ".jsonl"))))
    robot, xi = calibrated_model(doc)
    x = np.r_[xi, [doc["parameters"][k]["value"] for k in trace.extra_params()]]
    model = build("sm-markers", robot, trace.method_data(use="validation"), x)
    e = model.point_errors(model.evaluate(x)[0])
    return float(np.sqrt(np.mean(e[model.marker_of == 0] ** 2)))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", required=True, type=Path,
                    help="folder with the two CSVs and tiago_48_schunk.urdf")
    a = ap.parse_args()
    for name, sha in FILES.items():
        path = a.data / name
        if not path.is_file():
            print(f"missing {path}: see docs/urdf-robots.md for the download")
            return 2
        if sha and hashlib.sha256(path.read_bytes()).hexdigest() != sha:
            print(f"{path}: not FIGAROH's file (sha256 differs)")
            return 2
    rows = []
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        doc, text, _ = calibrate(tmp, a.data, [1], hold="j*", tag="o1")
        rows.append(("joint offsets, marker 1", *figures(doc, text), "2.88 / 4.23 / 12.0"))
        doc, text, _ = calibrate(tmp, a.data, [1], tag="f1")
        rows.append(("full model, marker 1", *figures(doc, text), "- / 3.07 / -"))
        doc4, text4, p4 = calibrate(tmp, a.data, [1, 2, 3, 4], tag="f4")
        rows.append(("full model, 4 points", *figures(doc4, text4), "(marker 1 only)"))
        for pts, tag in (([1], "c1"), ([1, 2, 3, 4], "c4")):
            docc, textc, _ = calibrate(tmp, a.data, pts, tag=tag, extra=["--compliance"])
            mc = docc["model_comparison"]
            f = mc.get("compliant") or {}
            held = f.get("held_out_rms")
            rows.append((f"+ compliance, {'marker 1' if len(pts) == 1 else '4 points'}",
                         f.get("fit_rms", math.nan) * 1e3 if f else math.nan,
                         held * 1e3 if held else math.nan, math.nan,
                         f.get("identifiable", 0), "supported" if mc["supported"] else
                         "not supported: " + mc["statement"].split(":")[0][:40]))
            print(f"compliance, {len(pts)} point(s): {mc['statement']}")
        print(f"{'calibration':<26}{'fit 3D RMS':>11}{'held-out':>10}{'max':>8}{'params':>7}"
              f"   FIGAROH fit / held-out / max (mm)")
        def mm(v, width, digits):     # a figure the parameter file does not hold: "-"
            return f"{v:>{width}.{digits}f}mm" if math.isfinite(v) else f"{'-':>{width + 2}}"

        for lab, fit, held, mx, n_id, fig in rows:
            print(f"{lab:<26}{mm(fit, 9, 3)}{mm(held, 8, 3)}{mm(mx, 6, 2)}{n_id:>7d}   {fig}")
        print(f"4-point fit, marker 1's held-out 3D RMS alone: {marker_one_heldout(p4) * 1e3:.3f} mm")
        print(f"(gate of the full marker-1 fit: {[ln for ln in text.splitlines() if 'outlier' in ln]})")
        # the same data turned anywhere
        c, s = np.cos(1.1), np.sin(1.1)
        turn = (np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]]) @
                np.array([[1, 0, 0], [0, np.cos(0.7), -np.sin(0.7)], [0, np.sin(0.7), np.cos(0.7)]]))
        docT, textT, _ = calibrate(tmp, a.data, [1, 2, 3, 4], turn=turn, tag="t4")
        worst = 0.0
        for k, p in doc4["parameters"].items():
            if k.startswith("base_") or not p["identifiable"]:
                continue
            q = docT["parameters"][k]
            worst = max(worst, abs(p["value"] - q["value"]) / max(abs(p["value"]), 1e-3))
        print(f"turned by an arbitrary rotation: robot and points differ by {worst:.2g} "
              f"(relative); held-out {figures(docT, textT)[1]:.4f} mm against "
              f"{figures(doc4, text4)[1]:.4f} mm")
        # the export
        rc, text = app("params", "export", p4, "--urdf", tmp / "cal.urdf")
        assert rc == 0, text
        import yourdfpy

        from station.outputs.export import calibrated_model

        robot, xi = calibrated_model(doc4)
        u0 = yourdfpy.URDF.load(str(a.data / "tiago_48_schunk.urdf"), load_meshes=False)
        u1 = yourdfpy.URDF.load(str(tmp / "cal.urdf"), load_meshes=False)
        same = ([j.name for j in u0.robot.joints] == [j.name for j in u1.robot.joints] and
                [lk.name for lk in u0.robot.links] == [lk.name for lk in u1.robot.links])
        x0 = xi.copy()
        for n in robot.param_names:
            if n.startswith("base_"):
                x0[robot.index(n)] = 0.0
        qm = np.random.default_rng(0).uniform(robot.limits[:, 0], robot.limits[:, 1], (200, 8))
        T = robot.frames(qm, x0)
        err = 0.0
        for q, Ti in zip(qm, T):
            u1.update_cfg(dict(zip(robot.spec.joint_names, q)))
            err = max(err, float(np.abs(u1.get_transform("wrist_ft_tool_link",
                                                          "base_footprint") - Ti).max()))
        print(f"export: {len(u1.robot.joints)} joints and {len(u1.robot.links)} links, names "
              f"{'kept' if same else 'CHANGED'}; FK against the parameter file: {err:.2g} m")
    return 0


if __name__ == "__main__":
    sys.exit(main())
