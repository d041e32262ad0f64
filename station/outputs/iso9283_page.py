"""The accuracy test's HTML page (``app.py accuracy``, the wizard's Accuracy step;
docs/accuracy.md): one self-contained file in the session report's look.

It is rebuilt from the accuracy CSV and the parameter file
(:func:`station.outputs.iso9283_csv.read`), so that it can be written again at any time
(``app.py accuracy --params P --csv C``). Its figures are those printed (the same
functions format both: :func:`station.outputs.iso9283.table`, :func:`~station.outputs.
iso9283.summary`). The page is the Jinja2 template ``station/templates/accuracy.html.j2``
in the report's environment and stylesheet (:func:`station.outputs.report.
template_environment`, ``report.css``), its figures drawn with the report's kit
(:mod:`station.outputs.iso9283_figures`); written atomically.

The session's report (``report.html``) is written when the session calibrates, before
any test. Where it lies beside the parameter file and is that file's (its checksum is
in it), :func:`link_report` adds a short section to it (replacing an earlier test's):
the test's headline and a link to the page. Any other report is left as it is.
"""
from __future__ import annotations

import math
import os
import re
from pathlib import Path

import numpy as np

from calibration import iso9283
from drivers.atomic import write_atomic
from station.outputs.iso9283 import PROGRAMS, summary, table
from station.outputs.params_file import file_sha256
from station.outputs.report import collector_paused, template_environment
from station.recording.trace import utc_now

TEMPLATE, LINK = "accuracy.html.j2", "accuracy_link.html.j2"
#: the section :func:`link_report` adds to a report, between these marks
MARKS = ("<!-- accuracy test (app.py accuracy) -->", "<!-- /accuracy test -->")

NOT_COVERED = (
    "The standard's other tests: distance accuracy and repeatability, path accuracy and "
    "repeatability, the stabilization time, the drift over hours, the multi-directional "
    "pose accuracy variation; its warm-up is left to the operator.",
    "Speeds and load: the test ran at the drives' configured speed with the robot's "
    "payload as it is; the standard's runs at 100 %, 50 % and 10 % of the rated speed with "
    "the rated load.",
    "One cube, one tool orientation: the pose accuracy elsewhere in the workspace, and at "
    "other orientations, is not measured here.",
    "The instrument: a motion capture measures AP well and RP only down to its own noise "
    "(its averaged frames); a laser tracker is the instrument for a robot's RP. Before and "
    "after are compared in the calibrated instrument frame, whose own error is in both "
    "alike.",
)


def headline(f) -> str:
    b, a = f.rms("nominal"), f.rms("compensated")
    rb = np.mean([p.rp for p in f.res["nominal"]])
    ra = np.mean([p.rp for p in f.res["compensated"]])
    return (f"AP_P {b * 1e3:.3f} mm RMS before the calibration, {a * 1e3:.3f} mm after: "
            f"{f.factor:.1f} times closer; RP_l {rb * 1e3:.3f} mm before, {ra * 1e3:.3f} mm "
            "after")


def render(f, *, title: str | None = None) -> str:
    """The page's HTML text of :class:`~station.outputs.iso9283_csv.Figures` ``f``."""
    from station.outputs import iso9283_figures

    with collector_paused():
        figs = iso9283_figures.figures(f)
    page = {"title": title or f"Accuracy test (ISO 9283): {f.robot}, "
                              f"{os.path.basename(f.params_path)}",
            "headline": headline(f), "created": utc_now(), "summary": _summary(f),
            "printed": table(f.res),
            "points": _points(f), "position": _position(f), "components": _components(f),
            "orientation": _orientation(f) if f.orientation else None, "figures": figs,
            "lines": summary(f.res, f.cycles, f.predicted_rms), "not_covered": NOT_COVERED,
            "rebuild": (f"python app.py accuracy --params {f.params_path} --csv {f.csv_path}")}
    return template_environment().get_template(TEMPLATE).render(**page)


def write(path, f) -> Path:
    """Write the page of ``f`` atomically to ``path``."""
    path = Path(path)
    write_atomic(path, render(f).encode("utf-8"))
    return path


def link_report(report, page, f) -> str:
    """Add the test's section to the session's report ``report`` (module doc), linking
    ``page``; what was done, in one line."""
    report = Path(report)
    try:
        text = report.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError):
        return f"{report} could not be read: not linked"
    checksum = str(f.doc.get("checksum", ""))
    if not checksum or checksum not in text or "<footer>" not in text:
        return (f"{report} is not the report of {os.path.basename(f.params_path)} (its "
                "checksum is not in it): the page is not linked from it")
    href = os.path.relpath(Path(page).resolve(), report.resolve().parent)
    section = template_environment().get_template(LINK).render(
        marks=MARKS, headline=headline(f), href=Path(href).as_posix(), created=utc_now(),
        cycles=f.cycles, csv=os.path.basename(f.csv_path))
    old = re.compile(re.escape(MARKS[0]) + ".*?" + re.escape(MARKS[1]) + r"\n?", re.S)
    text = old.sub("", text)
    at = text.rindex("<footer>")
    write_atomic(report, (text[:at] + section + "\n" + text[at:]).encode("utf-8"))
    return f"linked from {report}"


# -- the page's tables ---------------------------------------------------------------------
def _mm(v: float) -> str:
    return f"{v * 1e3:.3f}" if math.isfinite(v) else "\u2013"


def _summary(f) -> list[tuple[str, str]]:
    doc, cube = f.doc, f.centre * 1e3
    src = doc.get("robot_file") or {}
    frame = (doc.get("urdf") or {}).get("measurement_frame") or {}
    xyz = ", ".join(f"{v * 1e3:.1f}" for v in frame.get("xyz", ()))
    rpy = ", ".join(f"{math.degrees(v):.3f}" for v in frame.get("rpy", ()))
    z = f.tool[:, 2]
    left = [f"{prog} {pose}: {n}" for prog in PROGRAMS
            for pose, n in zip(iso9283.POINTS, f.left_out[prog]) if n]
    rows = [
        ("Robot", f"{f.robot} ({src.get('name', 'URDF')}, the chain {f.chain})"),
        ("Parameter file", f"{os.path.basename(f.params_path)}: {doc.get('method')}, written "
                           f"{doc.get('created', '')}, {doc.get('checksum', '')}"),
        ("Measurements", f"{os.path.basename(f.csv_path)}: {2 * 5 * f.cycles} rows, "
                         f"SHA-256 {_sha(f.csv_path)}"),
        ("Test cube", f"edge {f.size * 1e3:.1f} mm about ({', '.join(f'{v:.1f}' for v in cube)}"
                      f") mm in the base link frame, its edges along that frame's axes; "
                      "the measuring plane C1-C2-C7-C8, P1 its centre, P2..P5 at 10 % of the "
                      "diagonal from C1, C2, C7, C8 (ISO 9283, 6.2)"),
        ("Tool", f"{f.what}; one orientation throughout: its z axis along "
                 f"({', '.join(f'{v:+.3f}' for v in z)}) of the base link frame"),
        ("Instrument frame", f"the motion capture's; the base link in it, as the calibration "
                             f"placed it: ({xyz}) mm, roll, pitch, yaw ({rpy})\u00b0"
                             if xyz else "the motion capture's, as the calibration placed it"),
        ("Cycles", f"{f.cycles} of each program (the standard's {iso9283.CYCLES}), each P1, P5, "
                   "P4, P3, P2, every pose approached from the one before it"),
        ("Programs", "before: the nominal program (the nominal model's inverse kinematics, as "
                     "the controller runs it without the calibration); after: the compensated "
                     "program (the same targets, app.py compensate's values)"),
        ("Measured", "; ".join(f"{prog} {a} to {b}" for prog, (a, b) in f.times.items())),
        ("Left out", "none" if not left else
         "cycles of " + ", ".join(left) + " (a point on the tool not seen, or a fault): not "
         "in that pose's figures"),
    ]
    return rows


def _sha(path) -> str:
    try:
        return file_sha256(path)
    except OSError:
        return "unavailable"


def _points(f) -> list[dict]:
    P = iso9283.measuring_points(f.centre, f.size)
    cmd = P @ f.frame[:3, :3].T + f.frame[:3, 3]
    return [{"name": n, "base": [f"{v * 1e3:.1f}" for v in P[k]],
             "instrument": [f"{v * 1e3:.1f}" for v in cmd[k]]}
            for k, n in enumerate(iso9283.POINTS)]


def _position(f) -> dict:
    b, a = f.res["nominal"], f.res["compensated"]
    rows = [{"name": x.name, "n": f"{x.n}, {y.n}",
             "cells": [_mm(x.ap), _mm(y.ap), f"{x.ap / max(y.ap, 1e-12):.1f}", _mm(x.rp),
                       _mm(y.rp), _mm(p)]}
            for x, y, p in zip(b, a, f.predicted)]
    mean = [np.mean([p.ap for p in b]), np.mean([p.ap for p in a]), math.nan,
            np.mean([p.rp for p in b]), np.mean([p.rp for p in a]), math.nan]
    rms = [f.rms("nominal"), f.rms("compensated"), math.nan, math.nan, math.nan,
           f.predicted_rms if f.predicted_rms is not None else math.nan]
    cells = [_mm(v) for v in mean]
    cells[2] = ""
    rcells = [_mm(v) if math.isfinite(v) else "" for v in rms]
    rcells[2] = f"{f.factor:.1f}"
    return {"rows": rows, "mean": cells, "rms": rcells}


def _components(f) -> list[dict]:
    R = f.frame[:3, :3]
    out = []
    for x, y in zip(f.res["nominal"], f.res["compensated"]):
        cells = [f"{v * 1e3:+.3f}" for r in (x, y) for v in np.asarray(r.ap_xyz) @ R]
        cells += [_mm(v) for r in (x, y) for v in (r.lbar, r.s_l)]
        out.append({"name": x.name, "cells": cells})
    return out


def _orientation(f) -> list[dict]:
    out = []
    for x, y in zip(f.res["nominal"], f.res["compensated"]):
        cells = [f"{math.degrees(v):+.4f}" for r in (x, y) for v in r.ap_abc]
        cells += [f"{math.degrees(v):.4f}" for r in (x, y) for v in r.rp_abc]
        out.append({"name": x.name, "cells": cells})
    return out
