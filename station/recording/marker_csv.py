"""Reading a motion capture's or a tracker's CSV for ``sm-markers``
(:mod:`station.recording.import_markers`): the columns (joints of the URDF or of a joint
map, points on the tool, ``use``), every row's numbers and units, the joint limits; every
error names the file, line and column."""
from __future__ import annotations

import csv
import math
import os
import re

from calibration.errors import ConfigError
from station.recording.csv_columns import ANGLE, LENGTH, not_a_number, open_csv

USES = ("fit", "validation")
_POINT = (re.compile(r"^m(\d+)_([xyz])$"), re.compile(r"^([xyz])(\d+)$"))
# A joint value beyond the URDF's limit by at most this share of the joint's range
# (and at least LIMIT_SLACK_MIN) is an encoder at its end stop: a warning.
LIMIT_SLACK = 0.05
LIMIT_SLACK_MIN = {"R": math.radians(1.0), "P": 0.002}


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


class MarkerReader:
    """Reads the CSV files of one import (shared column layout checks)."""

    def __init__(self, robot, spec, length_unit, angle_unit, jmap, ignore):
        self.robot, self.spec, self.jmap = robot, spec, jmap
        self.lu, self.au = LENGTH[length_unit], ANGLE[angle_unit]
        self.units = (length_unit, angle_unit)
        self.ignore = set(ignore)
        self.n_points = None
        self.warnings: list[str] = []
        self.lines: list[str] = []       # "file:line" of each pose read
        self.beyond: dict = {}           # (joint, side) -> [count, largest, where, limit, unit]
        self.columns: dict = {}          # URDF joint -> the column its value was read from

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
                if a in points.get(j, {}):
                    raise ConfigError(f"columns {head[points[j][a]]!r} and {c!r} are both point "
                                      f"{j}'s {a}: keep one (--ignore-columns the other)",
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
                self.lines.append(f"{path}:{lineno}")
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
                raise ConfigError(f"column {head[ci]}: {not_a_number(v)}",
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
        if default_use == "validation" and use != "validation":
            raise ConfigError(f"column use: {use!r} in the held-out file (--validation): every "
                              "row of it is held out; remove the use column or say validation",
                              source=where)
        given = {c: num(ci) for c, ci in joint_cols.items()}
        qm = []
        for i, (nm, jt) in enumerate(zip(names, self.spec.joints), start=1):
            if self.jmap and nm in self.jmap.terms:
                v, col = self.jmap.value(nm, given), f"{nm} (joint map)"
            else:
                col = next(c for c in (nm, f"qm{i}") if c in given)
                v = given[col]
            self.columns.setdefault(nm, col)
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
        # where the user finds the pose: the file's name and its line
        rec = {"index": index, "qm": qm, "markers": pts,
               "source": f"{os.path.basename(path)}:{lineno}"}
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
        if beyond <= slack:      # counted per joint and side: said once (limit_warnings)
            seen = self.beyond.setdefault((jt.name, side), [0, 0.0, where, hi if v > hi else lo,
                                                            unit])
            seen[0] += 1
            if beyond > seen[1]:
                seen[1], seen[2] = beyond, f"pose {index} ({where})"
            return v
        unit_hint = ("are the joint values in degrees? (--angle-unit deg)" if jt.kind == "R" and
                     self.au == 1.0 and abs(v) > 2 * math.pi else
                     "are the joint values in mm? (--length-unit mm)" if jt.kind == "P" and
                     self.lu == 1.0 and abs(v) > 10 * max(abs(lo), abs(hi), 0.1) else
                     "check the column's unit, sign and zero (--joint-map)")
        raise ConfigError(f"column {col}: {_fmt(v)} {unit} is far outside the joint's limits "
                          f"[{_fmt(lo)}, {_fmt(hi)}] {unit} of the URDF: {unit_hint}",
                          source=where)

    def check_prismatic_units(self, poses: list, src: str) -> None:
        """A prismatic joint's column in metres read in ``--length-unit mm`` (a controller
        printing its rail in m beside a tracker's mm): its values then move by a
        thousandth of the URDF's travel. Refused, naming the column and the remedy."""
        if self.lu == 1.0 or not poses:
            return
        for i, (nm, jt) in enumerate(zip(self.spec.joint_names, self.spec.joints)):
            lo, hi = jt.limits
            travel = hi - lo
            if jt.kind != "P" or not (0 < travel < math.inf):
                continue
            v = [p["qm"][i] for p in poses]
            span = max(v) - min(v)
            as_m = [x / self.lu for x in v]
            slack = max(LIMIT_SLACK * travel, LIMIT_SLACK_MIN["P"])
            if (span < 0.01 * travel and max(as_m) - min(as_m) >= 0.05 * travel
                    and lo - slack <= min(as_m) and max(as_m) <= hi + slack):
                raise ConfigError(
                    f"column {self.columns.get(nm, nm)}: the prismatic joint {nm} moves "
                    f"{span * 1e3:.3g} mm over the poses, {100 * span / travel:.2g} % of "
                    f"its {_fmt(travel)} m travel in the URDF; its values look like metres "
                    f"read in {self.units[0]} (--length-unit applies to prismatic joints too): "
                    f"give it a joint map line with scale = {_fmt(1 / self.lu)} (--joint-map)",
                    source=src)

    def limit_warnings(self) -> list[str]:
        """One warning per joint and side for the values a little beyond the URDF's limit
        (an encoder at its end stop): how many, the largest and where."""
        out = []
        for (joint, side), (n, most, where, limit, unit) in self.beyond.items():
            if n == 1:
                out.append(f"{where}: {joint} is {_fmt(most)} {unit} beyond its {side} limit "
                           f"{_fmt(limit)} {unit} (the URDF's); kept")
            else:
                out.append(f"{joint}: {n} poses beyond its {side} limit {_fmt(limit)} {unit} "
                           f"(the URDF's), by up to {_fmt(most)} {unit} at {where}; kept")
        return out
