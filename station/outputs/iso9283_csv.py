"""What an accuracy CSV says (``app.py accuracy``'s, docs/accuracy.md): the ISO 9283
figures rebuilt from its rows and the parameter file the test was run with, for what is
printed, the HTML page (:mod:`station.outputs.iso9283_page`) and the wizard's step.

The rows are the record: AP and RP come from the attained and commanded points in them
(:func:`calibration.iso9283.pose_result`; a row whose points were not all seen, or left
out after a fault, is left out of its pose's figures and counted). The parameter file
gives what the rows do not: the test cube (the nominal model at the nominal program's
joint values: P1 its centre, its edge from P2..P5) and the calibration's predicted
error at the compensated program's values. A CSV that is not of that file is refused
in one line, naming both: its joints must be the file's robot's, its nominal program a
test cube's five points in the file's nominal model, its compensated program must
bring the file's calibrated model to them, and its commanded points must be where the
file's instrument frame puts them (each within :data:`TOL`).
"""
from __future__ import annotations

import csv
import io
import math
import os
from dataclasses import dataclass, field

import numpy as np

from calibration import iso9283
from calibration.errors import ConfigError
from station.outputs.iso9283 import PROGRAMS, check_file, view_frame
from station.outputs.params_file import check_usable, read_params

#: how far (m) the CSV's poses may be from the parameter file's: the solvers' own
#: tolerance (1e-6 m) and the CSV's rounding, with room
TOL = 1e-5
XYZ = ("x", "y", "z")
REQUIRED = ("program", "cycle", "pose", "t", *(f"cmd_{c}_mm" for c in XYZ),
            *(f"{c}_mm" for c in XYZ), "error_mm")


@dataclass
class Figures:
    """One test's figures (module doc). ``res``: program -> the five poses'
    :class:`~calibration.iso9283.PoseResult` (m, rad); ``predicted (5,)`` the
    calibration's std of the tool at the compensated poses (m; NaN unknown);
    ``centre``, ``size``, ``tool (3, 3)``: the cube in the base link frame; ``frame (4,
    4)``: the base link in the instrument's; ``scatter``: program -> per pose the
    attained points less their barycentre, along the base link's axes ``(n, 3)`` m;
    ``left_out``: program -> per pose the cycles not in its figures; ``times``: program
    -> (first, last) snapshot."""

    res: dict
    cycles: int
    predicted: np.ndarray
    centre: np.ndarray
    size: float
    tool: np.ndarray
    frame: np.ndarray
    scatter: dict
    left_out: dict
    times: dict
    orientation: bool
    robot: str
    chain: str
    what: str
    csv_path: str
    params_path: str
    doc: dict = field(repr=False, default_factory=dict)

    @property
    def predicted_rms(self) -> float | None:
        p = self.predicted
        return float(np.sqrt(np.mean(p ** 2))) if np.isfinite(p).all() else None

    def rms(self, program: str) -> float:
        return float(np.sqrt(np.mean([p.ap ** 2 for p in self.res[program]])))

    @property
    def factor(self) -> float:
        return self.rms("nominal") / max(self.rms("compensated"), 1e-12)


def read(csv_path, params_path, *, text: str | None = None, doc: dict | None = None) -> Figures:
    """The :class:`Figures` of the accuracy CSV ``csv_path`` (its ``text`` where given)
    and the parameter file ``params_path`` (its read content ``doc`` where given);
    ConfigError in one line where either cannot be read or they do not belong together."""
    from station.outputs.compensate import setup

    csv_path, params_path = str(csv_path), str(params_path)
    if doc is None:
        doc = read_params(params_path)
        check_usable(doc, params_path)
    check_file(doc, params_path)
    if text is None:
        try:
            with open(csv_path, encoding="utf-8", newline="") as f:
                text = f.read()
        except OSError as e:
            raise ConfigError(f"cannot read the accuracy CSV: {e.strerror or e}",
                              source=csv_path) from None
        except UnicodeDecodeError:
            raise ConfigError("not a text file (app.py accuracy's CSV)", source=csv_path) \
                from None
    s = setup(doc, params_path)
    rows, joints, angles = _rows(text, csv_path)
    name = os.path.basename(params_path)
    if tuple(joints) != tuple(s.names):
        raise ConfigError(f"its joints ({', '.join(joints)}) are not those of {name}'s robot "
                          f"({', '.join(s.names)})", source=csv_path)
    if angles != s.comp.orientation:
        raise ConfigError(f"it {'has' if angles else 'has no'} orientation columns (a_deg, ..) "
                          f"where {name}'s calibration {'does not fix' if angles else 'fixes'} "
                          "the tool's orientation: it is another calibration's test",
                          source=csv_path)
    cycles, table = _cycles(rows, csv_path)
    q = {p: np.array([table[p][1][k]["q"] for k in iso9283.POINTS]) for p in PROGRAMS}
    cmd = np.array([table["nominal"][1][k]["cmd"] for k in iso9283.POINTS])
    x_view, frame = view_frame(s.robot, doc["parameters"], s.comp.xi_cal)
    T = s.comp.targets(q["nominal"])
    centre, size = _cube(T, csv_path, name)
    _belongs(s.comp, frame, T, q["compensated"], cmd, csv_path, name)
    cov = doc["covariance"]
    sp, _sa = s.comp.predicted(q["compensated"], list(cov["names"]),
                               np.asarray(cov["matrix"], dtype=float))
    res, scatter, left, times = {}, {}, {}, {}
    for prog in PROGRAMS:
        res[prog], scatter[prog], left[prog] = [], [], []
        for k, pose in enumerate(iso9283.POINTS):
            got = [table[prog][c][pose] for c in range(1, cycles + 1)]
            pos = np.array([g["pos"] for g in got])
            ok = np.isfinite(pos).all(axis=1)
            if ok.sum() < 2:
                raise ConfigError(f"{prog} program, {pose}: every point seen in {int(ok.sum())} "
                                  "cycle(s); AP and RP need two at least", source=csv_path)
            ang = np.array([g["abc"] for g in got])[ok] if angles else None
            if ang is not None and not np.isfinite(ang).all():
                raise ConfigError(f"{prog} program, {pose}: an orientation is missing where the "
                                  "point is given", source=csv_path)
            res[prog].append(iso9283.pose_result(pose, pos[ok], cmd[k], ang))
            scatter[prog].append((pos[ok] - pos[ok].mean(axis=0)) @ frame[:3, :3])
            left[prog].append(int((~ok).sum()))
        stamps = sorted(r["t"] for r in rows if r["program"] == prog and r["t"])
        times[prog] = (stamps[0], stamps[-1]) if stamps else ("", "")
    spec = s.robot.spec
    return Figures(res, cycles, np.asarray(sp, dtype=float), centre, size, T[0, :3, :3], frame,
                   scatter, left, times, bool(angles), str(doc.get("robot", "")),
                   f"{spec.base_link} to {spec.tip_link}", s.what, csv_path, params_path, doc)


def _number(text: str, where: str, csv_path: str, finite: bool = False) -> float:
    if text == "" and not finite:
        return math.nan
    try:
        v = float(text)
    except ValueError:
        v = math.nan
    if not math.isfinite(v):
        raise ConfigError(f"{where}: {text[:30]!r} is not a number", source=csv_path)
    return v


def _rows(text: str, csv_path: str):
    """``(rows, joints, angles)``: each row's program, cycle, pose, time, commanded and
    attained point (m, instrument frame), angles (rad) and commanded joint values."""
    reader = csv.reader(io.StringIO(text))
    head = next(reader, None) or []
    missing = [c for c in REQUIRED if c not in head]
    if missing:
        raise ConfigError(f"not an accuracy CSV (app.py accuracy's): no column {missing[0]}",
                          source=csv_path)
    col = {c: i for i, c in enumerate(head)}
    joints = [c[:-4] for c in head if c.endswith("_cmd")]
    angles = all(f"{c}_deg" in col for c in "abc")
    rows = []
    for line, cells in enumerate(reader, start=2):
        if not cells:
            continue
        if len(cells) != len(head):
            raise ConfigError(f"line {line}: {len(cells)} cells, the header has {len(head)}",
                              source=csv_path)

        def num(c, finite=False, _cells=cells, _line=line):
            return _number(_cells[col[c]].strip(), f"line {_line}, {c}", csv_path, finite)

        prog, cycle, pose = (cells[col[c]].strip() for c in ("program", "cycle", "pose"))
        if prog not in PROGRAMS or pose not in iso9283.POINTS or not cycle.isdigit() \
                or int(cycle) < 1:
            raise ConfigError(f"line {line}: program {prog[:20]!r}, cycle {cycle[:10]!r}, pose "
                              f"{pose[:10]!r} (expected nominal or compensated, 1, 2, .., "
                              "P1..P5)", source=csv_path)
        rows.append({"program": prog, "cycle": int(cycle), "pose": pose,
                     "t": cells[col["t"]].strip(), "line": line,
                     "cmd": np.array([num(f"cmd_{c}_mm", True) for c in XYZ]) * 1e-3,
                     "pos": np.array([num(f"{c}_mm") for c in XYZ]) * 1e-3,
                     "abc": (np.radians([num(f"{c}_deg") for c in "abc"]) if angles
                             else None),
                     "q": np.array([num(f"{j}_cmd", True) for j in joints])})
    return rows, joints, angles


def _cycles(rows, csv_path: str):
    """``(n, program -> cycle -> pose -> row)``: every cycle of both programs whole, the
    same n of each, each pose's commanded point and joint values the same in all."""
    table = {p: {} for p in PROGRAMS}
    for r in rows:
        got = table[r["program"]].setdefault(r["cycle"], {})
        if r["pose"] in got:
            raise ConfigError(f"line {r['line']}: {r['program']} cycle {r['cycle']} "
                              f"{r['pose']} twice", source=csv_path)
        got[r["pose"]] = r
    counts = {p: len(table[p]) for p in PROGRAMS}
    for prog, cyc in table.items():
        if sorted(cyc) != list(range(1, len(cyc) + 1)) or len(cyc) < 2:
            raise ConfigError(f"the {prog} program's cycles are {sorted(cyc)[:6] or 'none'}: "
                              "expected 1 to n, n >= 2", source=csv_path)
        for c, poses in cyc.items():
            if len(poses) != 5:
                lack = [k for k in iso9283.POINTS if k not in poses]
                raise ConfigError(f"{prog} cycle {c} has no row of {', '.join(lack)}",
                                  source=csv_path)
            for k, r in poses.items():
                first = cyc[1][k]
                if not (np.allclose(r["cmd"], first["cmd"], atol=1e-9, rtol=0)
                        and np.allclose(r["q"], first["q"], atol=1e-9, rtol=0)):
                    raise ConfigError(f"line {r['line']}: {prog} {k} commanded otherwise than "
                                      "in cycle 1", source=csv_path)
    if counts["nominal"] != counts["compensated"]:
        raise ConfigError(f"{counts['nominal']} cycles of the nominal program, "
                          f"{counts['compensated']} of the compensated one", source=csv_path)
    for k in iso9283.POINTS:
        a, b = table["nominal"][1][k]["cmd"], table["compensated"][1][k]["cmd"]
        if np.linalg.norm(a - b) > TOL:
            raise ConfigError(f"{k} is commanded {np.linalg.norm(a - b) * 1e3:.3f} mm apart in "
                              "the two programs", source=csv_path)
    return counts["nominal"], table


def _cube(T, csv_path: str, name: str):
    """``(centre, size)`` of the cube whose P1..P5 the targets ``T (5, 4, 4)`` are."""
    P = T[:, :3, 3]
    size = float(np.mean(np.linalg.norm(P[1:] - P[0], axis=1))) \
        / ((1 - 2 * iso9283.FRACTION) * math.sqrt(3) / 2)
    d = np.linalg.norm(iso9283.measuring_points(P[0], size) - P, axis=1) if size > 0 \
        else np.full(5, math.inf)
    if not np.all(d < TOL):
        k = int(np.argmax(d))
        raise ConfigError(f"its nominal program is not a test cube's P1..P5 in {name}'s nominal "
                          f"model ({iso9283.POINTS[k]} is {d[k] * 1e3:.3f} mm from where the "
                          "cube puts it): it is another robot's test", source=csv_path)
    return P[0].copy(), size


def _belongs(comp, frame, T, q_comp, cmd, csv_path: str, name: str) -> None:
    """The compensated program is this calibration's, the commanded points this frame's."""
    for k, pose in enumerate(iso9283.POINTS):
        pos, ang = comp.errors(q_comp[k], T[k])
        if pos > TOL or (math.isfinite(ang) and ang > 10 * TOL):
            raise ConfigError(f"it was not measured with {name}'s calibration: its compensated "
                              f"program's {pose} is {pos * 1e3:.3f} mm from the target in "
                              f"{name}'s calibrated model", source=csv_path)
    P = T[:, :3, 3] @ frame[:3, :3].T + frame[:3, 3]
    d = np.linalg.norm(P - cmd, axis=1)
    if not np.all(d < TOL):
        k = int(np.argmax(d))
        raise ConfigError(f"its commanded {iso9283.POINTS[k]} is {d[k] * 1e3:.3f} mm from where "
                          f"{name}'s instrument frame (base_*) puts it: it is another "
                          "calibration's test", source=csv_path)
