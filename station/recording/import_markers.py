"""``app.py trace import`` for a URDF robot and points on its tool (``sm-markers``):
a tracker's or a motion capture's export as it comes (docs/urdf-robots.md).

One row per pose, a header row naming the columns:

=============================  ====================================================
joint columns                  one per movable joint of the chain, named as in the URDF
                               (or ``qm1 .. qmN``); revolute in ``--angle-unit``,
                               prismatic in ``--length-unit``; or the controller's
                               columns of a joint map (``--joint-map``)
``m{j}_x, m{j}_y, m{j}_z``     point j on the tool in the instrument's frame
(or ``x{j}, y{j}, z{j}``)      (``--length-unit``); three empty cells: not seen
``use``                        ``fit`` (default) or ``validation`` (held out)
=============================  ====================================================

``--validation CSV`` adds the rows of another file (another day's session in the
same instrument frame) as held-out poses; ``--ignore-columns`` names columns to
skip (timestamps, the instrument's quality figures). Every error names the file,
line and column. A joint value a little beyond the URDF's limit (an encoder at its
end stop) is a warning naming the pose; far beyond, an error that names the unit.

The start values of the instrument's frame and of the points on the tool are
estimated here from the fit rows (:func:`calibration.methods.sm_markers.register`)
and written into the trace's ``nominal``; before that, the readings are checked
against the robot: their scale (a unit), a mirror (a sign-flipped or swapped
axis), and whether they follow the robot's motion at all (joint order, units,
signs).
"""
from __future__ import annotations

import csv
import hashlib
import math
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from calibration.errors import ConfigError
from calibration.methods.sm_markers import marker_names, register, scale_and_mirror
from calibration.robots import get_robot
from calibration.robots.serial import rpy_of
from drivers.urdf_file import load_urdf
from station.recording.csv_columns import ANGLE, LENGTH, open_csv

USES = ("fit", "validation")
_POINT = (re.compile(r"^m(\d+)_([xyz])$"), re.compile(r"^([xyz])(\d+)$"))
# A joint value beyond the URDF's limit by at most this share of the joint's range
# (and at least LIMIT_SLACK_MIN) is an encoder at its end stop: a warning.
LIMIT_SLACK = 0.05
LIMIT_SLACK_MIN = {"R": math.radians(1.0), "P": 0.002}
# The readings must follow the robot: after the best placement of the instrument's
# frame and the points, their median distance from the nominal robot's prediction is
# at most this share of the points' RMS spread (a nominal robot is off by millimetres;
# the median, so that a few gross readings are left to the fit-quality gate).
FOLLOW_SHARE = 0.1


@dataclass
class Imported:
    header: dict
    poses: list
    warnings: list


def _point_column(c: str):
    m = _POINT[0].match(c)
    if m:
        return int(m.group(1)), m.group(2)
    m = _POINT[1].match(c)
    if m:
        return int(m.group(2)), m.group(1)
    return None


def _fmt(v: float) -> str:
    return f"{v:.6g}"


class _Reader:
    """Reads the CSV files of one import (shared column layout checks)."""

    def __init__(self, robot, spec, length_unit, angle_unit, jmap, ignore):
        self.robot, self.spec, self.jmap = robot, spec, jmap
        self.lu, self.au = LENGTH[length_unit], ANGLE[angle_unit]
        self.units = (length_unit, angle_unit)
        self.ignore = set(ignore)
        self.n_points = None
        self.warnings: list[str] = []

    def joint_unit(self, kind: str) -> float:
        return self.au if kind == "R" else self.lu

    def layout(self, head: list[str], src: str):
        """Columns -> ``(joint_cols, point_cols, use_col)``; errors name the column."""
        names = self.spec.joint_names
        n = len(names)
        joint_cols: dict[str, int] = {}
        points: dict[int, dict[str, int]] = {}
        use = None
        mapped = set(self.jmap.terms) if self.jmap else set()
        wanted_from_map = self.jmap.columns if self.jmap else set()
        own = {}
        for i, nm in enumerate(names, start=1):
            if nm not in mapped:
                own[nm] = i
                own[f"qm{i}"] = i
        seen_own: dict[int, str] = {}
        for ci, c in enumerate(head):
            if c in self.ignore:
                continue
            if c == "use":
                use = ci
                continue
            pc = _point_column(c)
            if pc is not None:
                j, a = pc
                if j < 1:
                    raise ConfigError(f"column {c!r}: points are numbered from 1",
                                      source=f"{src}:1")
                points.setdefault(j, {})[a] = ci
                continue
            if c in wanted_from_map:
                joint_cols[c] = ci
                continue
            if c in own:
                i = own[c]
                if i in seen_own:
                    raise ConfigError(f"columns {seen_own[i]!r} and {c!r} are both joint {i} "
                                      f"({names[i - 1]})", source=f"{src}:1")
                seen_own[i] = c
                joint_cols[c] = ci
                continue
            hint = (f"joints: {', '.join(names)} (or qm1..qm{n})" +
                    (f", the joint map's columns {', '.join(sorted(wanted_from_map))}"
                     if self.jmap else ""))
            raise ConfigError(f"column {c!r} is not one sm-markers reads ({hint}; points "
                              f"m1_x, m1_y, m1_z ... or x1, y1, z1 ...; use); --ignore-columns "
                              f"skips the instrument's other columns", source=f"{src}:1")
        for i, nm in enumerate(names, start=1):
            if nm in mapped:
                continue
            if i not in seen_own:
                raise ConfigError(f"missing the column of joint {nm!r} (or qm{i}): the chain "
                                  f"{self.spec.base_link} -> {self.spec.tip_link} has joints "
                                  f"{', '.join(names)}", source=f"{src}:1")
        for c in sorted(wanted_from_map):
            if c not in joint_cols:
                raise ConfigError(f"missing the column {c!r} that the joint map reads",
                                  source=f"{src}:1")
        if not points:
            raise ConfigError("no point columns (m1_x, m1_y, m1_z ... or x1, y1, z1 ...)",
                              source=f"{src}:1")
        count = max(points)
        for j in range(1, count + 1):
            miss = [a for a in "xyz" if a not in points.get(j, {})]
            if miss:
                raise ConfigError(f"point {j} has no column for {', '.join(miss)} (points "
                                  f"1..{count} need x, y and z each)", source=f"{src}:1")
        if self.n_points is None:
            self.n_points = count
        elif count != self.n_points:
            raise ConfigError(f"{count} points, where the first file has {self.n_points}",
                              source=f"{src}:1")
        return joint_cols, points, use

    def read(self, path: str, default_use: str, poses: list) -> bytes:
        raw, head, rows = open_csv(path)
        if len(set(head)) != len(head):
            dup = sorted({c for c in head if head.count(c) > 1})
            raise ConfigError(f"column {dup[0]!r} is named twice", source=f"{path}:1")
        joint_cols, points, use_col = self.layout(head, path)
        names = self.spec.joint_names
        lineno = 1
        try:
            for lineno, row in enumerate(rows, start=2):
                if not any(v.strip() for v in row):
                    continue
                poses.append(self._row(row, head, path, lineno, joint_cols, points, use_col,
                                       default_use, names, len(poses)))
        except csv.Error as e:
            raise ConfigError(f"not a CSV row: {e}", source=f"{path}:{lineno}") from None
        return raw

    def _row(self, row, head, path, lineno, joint_cols, points, use_col, default_use, names,
             index):
        where = f"{path}:{lineno}"
        if len(row) != len(head):
            raise ConfigError(f"{len(row)} values for {len(head)} columns", source=where)

        def num(ci):
            v = row[ci].strip()
            try:
                x = float(v)
            except ValueError:
                raise ConfigError(f"column {head[ci]}: {v[:40]!r} is not a number",
                                  source=where) from None
            if not math.isfinite(x) or "_" in v:
                raise ConfigError(f"column {head[ci]}: {v[:40]!r} is not a finite number",
                                  source=where)
            return x

        use = row[use_col].strip() if use_col is not None else ""
        use = use or default_use
        if use not in USES:
            raise ConfigError(f"column use: {use[:40]!r} is not one of {', '.join(USES)}",
                              source=where)
        given = {c: num(ci) for c, ci in joint_cols.items()}
        qm = []
        for i, (nm, jt) in enumerate(zip(names, self.spec.joints), start=1):
            if self.jmap and nm in self.jmap.terms:
                v, col = self.jmap.value(nm, given), f"{nm} (joint map)"
            else:
                col = next(c for c in (nm, f"qm{i}") if c in given)
                v = given[col]
            qm.append(self._limit(v * self.joint_unit(jt.kind), jt, col, where, index))
        pts = []
        for j in range(1, self.n_points + 1):
            cells = [row[points[j][a]].strip() for a in "xyz"]
            if not any(cells):
                pts.append(None)
                continue
            if not all(cells):
                raise ConfigError(f"point {j}: some of its x, y, z cells are empty (leave all "
                                  f"three empty where the point was not seen)", source=where)
            pts.append([num(points[j][a]) * self.lu for a in "xyz"])
        if all(p is None for p in pts):
            raise ConfigError("no point seen in this row", source=where)
        rec = {"index": index, "qm": qm, "markers": pts}
        if use == "validation":
            rec["use"] = "validation"
        return rec

    def _limit(self, v: float, jt, col: str, where: str, index: int) -> float:
        lo, hi = jt.limits
        if jt.continuous or lo <= v <= hi:
            return v
        unit = "rad" if jt.kind == "R" else "m"
        beyond = lo - v if v < lo else v - hi
        slack = max(LIMIT_SLACK * (hi - lo), LIMIT_SLACK_MIN[jt.kind])
        side = "lower" if v < lo else "upper"
        if beyond <= slack:
            self.warnings.append(f"pose {index} ({where}): {jt.name} {_fmt(v)} {unit} is "
                                 f"{_fmt(beyond)} {unit} beyond its {side} limit "
                                 f"{_fmt(hi if v > hi else lo)} {unit} (the URDF's); kept")
            return v
        unit_hint = ("are the joint values in degrees? (--angle-unit deg)" if jt.kind == "R" and
                     self.au == 1.0 and abs(v) > 2 * math.pi else
                     "are the joint values in mm? (--length-unit mm)" if jt.kind == "P" and
                     self.lu == 1.0 and abs(v) > 10 * max(abs(lo), abs(hi), 0.1) else
                     "check the column's unit, sign and zero (--joint-map)")
        raise ConfigError(f"column {col}: {_fmt(v)} {unit} is far outside the joint's limits "
                          f"[{_fmt(lo)}, {_fmt(hi)}] {unit} of the URDF: {unit_hint}",
                          source=where)


def import_markers(csv_path, robot_path, *, base_link, tip_link, length_unit="m",
                   angle_unit="rad", sigma=None, validation=None, ignore=(),
                   joint_map=None) -> Imported:
    """The trace (header, poses) of a CSV (and a held-out CSV) for ``sm-markers``."""
    from station.recording.joint_map import load_joint_map

    spec = load_urdf(robot_path, base_link, tip_link)
    robot = get_robot(spec)
    if length_unit not in LENGTH or angle_unit not in ANGLE:
        raise ConfigError(f"units must be {'/'.join(LENGTH)} and {'/'.join(ANGLE)}, not "
                          f"{length_unit!r}, {angle_unit!r}", source=str(csv_path))
    jmap = load_joint_map(joint_map, spec.joint_names) if joint_map else None
    reader = _Reader(robot, spec, length_unit, angle_unit, jmap, ignore)
    poses: list = []
    files = [(str(csv_path), "fit")] + ([(str(validation), "validation")] if validation else [])
    digests = {}
    for path, use in files:
        before = len(poses)
        raw = reader.read(path, use, poses)
        if len(poses) == before:
            raise ConfigError("no poses (one row per pose after the header)", source=path)
        digests[path] = hashlib.sha256(raw).hexdigest()
    fit = [p for p in poses if p.get("use", "fit") == "fit"]
    if not fit:
        raise ConfigError("no fit rows (every row is held out)", source=str(csv_path))
    qm = np.array([p["qm"] for p in fit])
    pts = np.array([[[math.nan] * 3 if c is None else c for c in p["markers"]] for p in fit])
    nominal = start_values(robot, qm, pts, str(csv_path))
    imported = {"file": Path(str(csv_path)).name, "sha256": digests[str(csv_path)]}
    if validation:
        imported["validation"] = {"file": Path(str(validation)).name,
                                  "sha256": digests[str(validation)]}
    if jmap:
        imported["joint_map"] = dict(jmap.source)
    if ignore:
        imported["ignored_columns"] = sorted(ignore)
    header = {"robot": robot.name, "robot_file": dict(spec.source), "method": "sm-markers",
              "markers": reader.n_points, "nominal": nominal,
              "station": {"imported_from": imported,
                          "units": {"length": length_unit, "angle": angle_unit},
                          "joints": list(spec.joint_names)}}
    if sigma:
        header["sigma"] = sigma
    return Imported(header, poses, reader.warnings)


def start_values(robot, qm, pts, where: str) -> dict:
    """The nominal of the trace: the instrument frame and the points on the tool that
    best explain the fit rows with the robot at its URDF values; refuses readings
    that a unit, a mirror or a wrong joint column makes inconsistent with the robot."""
    xi = robot.nominal
    seen = np.all(np.isfinite(pts), axis=2)
    spread = float(np.sqrt(np.mean(np.sum((pts[seen] - pts[seen].mean(axis=0)) ** 2, axis=1))))
    scale, proper, mirrored = scale_and_mirror(robot, qm, pts, xi)
    if not 1 / 3 < scale < 3:
        hint = ("in mm? (--length-unit mm)" if scale > 100 else
                "in m? (--length-unit m)" if scale < 0.01 else
                "in another unit, or the joint values in another one (--angle-unit)")
        raise ConfigError(f"the points move {scale:.3g} times as far as the robot's tool does: "
                          f"are they {hint}", source=where)
    if mirrored < proper / 3 and proper > FOLLOW_SHARE * spread:
        raise ConfigError(f"the points fit the robot only mirrored ({mirrored * 1e3:.3g} mm "
                          f"mirrored, {proper * 1e3:.3g} mm as they are): the instrument's "
                          f"frame is left-handed in this export (an axis sign-flipped, or two "
                          f"axes swapped); no rotation gives that: export it right-handed",
                          source=where)
    if proper > FOLLOW_SHARE * spread:
        raise ConfigError(f"the points do not follow the robot: after the best placement of "
                          f"the instrument's frame they are {proper * 1e3:.3g} mm from the "
                          f"URDF's prediction (median), {proper / spread:.0%} of their spread: "
                          f"check the joint columns' order, units (--angle-unit, --length-unit), "
                          f"signs and zeros (--joint-map), that the points are fixed on the "
                          f"tool, and that the URDF describes this robot",
                          source=where)
    R, t, u, _rms = register(robot, qm, pts, xi)
    roll, pitch, yaw = rpy_of(R[None])[0]
    out = {"base_x": float(t[0]), "base_y": float(t[1]), "base_z": float(t[2]),
           "base_roll": float(roll), "base_pitch": float(pitch), "base_yaw": float(yaw)}
    out.update(zip(marker_names(len(u)), (float(v) for v in u.reshape(-1))))
    return out


def import_markers_command(args) -> str:
    """``trace import`` with a URDF robot: write the trace; returns a summary line and
    prints the warnings to stderr."""
    import sys

    from station.recording.trace_writer import write_trace
    from station.recording.csv_columns import parse_sigma

    ignore = tuple(c.strip() for c in (args.ignore_columns or "").split(",") if c.strip())
    got = import_markers(args.csv, args.robot, base_link=args.base_link, tip_link=args.tip_link,
                         length_unit=args.length_unit, angle_unit=args.angle_unit,
                         sigma=parse_sigma(args.sigma, ("marker",)), validation=args.validation,
                         ignore=ignore, joint_map=args.joint_map)
    for w in got.warnings:
        print(f"warning: {w}", file=sys.stderr)
    write_trace(args.out, got.header, None, got.poses)
    n_val = sum(1 for p in got.poses if p.get("use") == "validation")
    held = f", {n_val} held out" if n_val else ""
    return (f"trace written to {args.out} ({len(got.poses) - n_val} poses to fit{held}, "
            f"{got.header['markers']} points on the tool, robot {got.header['robot']} "
            f"{args.base_link} -> {args.tip_link}, sm-markers)")
