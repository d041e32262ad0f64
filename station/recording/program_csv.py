"""A robot program as a CSV of joint values (``app.py compensate``, docs/compensation.md):
read it, and write it back with other joint values in the same columns and units.

One row per target, a header row naming the columns. The joint columns are named as
the robot's joints (a URDF's joint names) or ``qm1 .. qmN``, or they are the
controller's columns of a joint map (:mod:`station.recording.joint_map`); every other
column (a program's line numbers, speeds, comments) is passed through unchanged. A
column that names a joint the robot does not have (``qm7`` of a six-joint arm, a
URDF joint outside the chain, a joint the map already gives) is refused, as are a
missing joint column, a cell that is not a number and a compensated program's own
columns (:data:`RESULT_COLUMNS`). Every error names the file, line and column
(:func:`station.recording.csv_columns.open_csv`).

The joint values are read in the CSV's units and converted by ``scales`` (the CSV
unit in the model's: ``--angle-unit``/``--length-unit`` for a URDF's revolute and
prismatic joints, 1 for a robot file's actuator units). Written back through a joint
map, the controller's columns change by the least that gives the new joint values
(exactly: a map whose joints the columns cannot each set is refused).
"""
from __future__ import annotations

import csv
import io
import math
import re
from dataclasses import dataclass, field

import numpy as np

from calibration.errors import ConfigError
from station.recording.csv_columns import SEPARATORS, not_a_number, open_csv

#: the columns a compensated program adds
RESULT_COLUMNS = ("residual_mm", "residual_deg", "status")
_QM = re.compile(r"^qm(\d+)$")


@dataclass
class Program:
    """A program read: ``head`` the columns, ``sep`` their separator, ``rows`` the cells
    of every row (blank lines left out) and ``lines`` its line number; ``values (m, n)``
    the joint values in the model's units; ``columns`` joint index -> the column (or
    ``"J3 (joint map)"``) its value came from; ``cells`` every joint column -> its index."""

    path: str
    head: list
    sep: str
    rows: list = field(default_factory=list)
    lines: list = field(default_factory=list)
    values: np.ndarray | None = None
    columns: dict = field(default_factory=dict)
    cells: dict = field(default_factory=dict)

    def where(self, k: int) -> str:
        return f"{self.path}:{self.lines[k]}"


def _layout(head, src, names, n, jmap, others):
    """Column -> joint: ``(own {column: joint index}, map columns {column})``."""
    mapped = set(jmap.terms) if jmap else set()
    wanted = jmap.columns if jmap else set()
    own = {}
    for i in range(n):
        nm = names[i] if names else None
        if nm in mapped:
            continue
        if nm:
            own[nm] = i
        own[f"qm{i + 1}"] = i
    joints = ", ".join(names) if names else f"qm1..qm{n}"
    got, seen = {}, {}
    for c in head:
        if c in RESULT_COLUMNS:
            raise ConfigError(f"column {c!r} is one compensate writes: is this a compensated "
                              "program already? compensate the program the nominal "
                              "controller runs", source=f"{src}:1")
        if c in wanted:
            got[c] = None
            continue
        if c in own:
            i = own[c]
            if i in seen:
                raise ConfigError(f"columns {seen[i]!r} and {c!r} are both joint {i + 1}",
                                  source=f"{src}:1")
            seen[i] = c
            got[c] = i
            continue
        m = _QM.match(c)
        joint = names[int(m.group(1)) - 1] if m and names and 0 < int(m.group(1)) <= n else c
        if m or c in others or joint in mapped:
            why = (f"the joint map gives {joint} from its columns "
                   f"{', '.join(k for k, _ in jmap.terms[joint])}" if joint in mapped else
                   f"not a movable joint of the robot (its joints: {joints})")
            raise ConfigError(f"column {c!r}: {why}", source=f"{src}:1")
    for i in range(n):
        nm = names[i] if names else None
        if nm not in mapped and i not in seen:
            what = f"{nm!r} (or qm{i + 1})" if nm else f"qm{i + 1}"
            raise ConfigError(f"missing the column of joint {what}: the robot's joints are "
                              f"{joints}", source=f"{src}:1")
    for c in sorted(wanted - set(got)):
        raise ConfigError(f"missing the column {c!r} that the joint map reads",
                          source=f"{src}:1")
    return got


def read_program(path, names, scales, jmap=None, others=()) -> Program:
    """The program in the CSV ``path`` (module doc) of a robot whose ``n = len(scales)``
    joints are named ``names`` (a URDF's; empty: ``qm1 .. qmN`` only); ``others`` the
    URDF's joints outside the chain; ``jmap`` a joint map or None."""
    src = str(path)
    raw, head, rows = open_csv(src)
    first = raw.decode("utf-8-sig").split("\n", 1)[0]
    prog = Program(src, head, next((c for c in SEPARATORS if c in first), ","))
    if len(set(head)) != len(head):
        dup = sorted({c for c in head if head.count(c) > 1})
        raise ConfigError(f"column {dup[0]!r} is named twice", source=f"{src}:1")
    n = len(scales)
    got = _layout(head, src, names, n, jmap, set(others))
    prog.cells = {c: head.index(c) for c in got}
    values, lineno = [], 1
    try:
        for lineno, row in enumerate(rows, start=2):
            if not any(v.strip() for v in row):
                continue
            where = f"{src}:{lineno}"
            if len(row) != len(head):
                raise ConfigError(f"{len(row)} values for {len(head)} columns", source=where)
            given = {c: _number(row[ci], c, where) for c, ci in prog.cells.items()}
            q = []
            for i in range(n):
                nm = names[i] if names else None
                if jmap and nm in jmap.terms:
                    v, col = jmap.value(nm, given), f"{nm} (joint map)"
                else:
                    col = next(c for c, j in got.items() if j == i)
                    v = given[col]
                prog.columns.setdefault(i, col)
                q.append(v * scales[i])
            values.append(q)
            prog.rows.append(list(row))
            prog.lines.append(lineno)
    except csv.Error as e:
        raise ConfigError(f"not a CSV row: {e}", source=f"{src}:{lineno}") from None
    if not values:
        raise ConfigError("no targets (one row per target after the header)", source=src)
    prog.values = np.array(values, dtype=float)
    return prog


def _number(cell: str, col: str, where: str) -> float:
    v = cell.strip()
    try:
        x = float(v)
    except ValueError:
        raise ConfigError(f"column {col}: {not_a_number(v)}", source=where) from None
    if not math.isfinite(x) or "_" in v:
        raise ConfigError(f"column {col}: {v[:40]!r} is not a finite number", source=where)
    return x


def check_map_writable(jmap, src: str) -> None:
    """Refuse a joint map whose columns cannot set each of its joints (written back, the
    compensated joint values must come out of the controller's columns exactly)."""
    joints, cols = list(jmap.terms), sorted(jmap.columns)
    A = np.zeros((len(joints), len(cols)))
    for r, nm in enumerate(joints):
        for c, k in jmap.terms[nm]:
            A[r, cols.index(c)] += k
    if np.linalg.matrix_rank(A) < len(joints):
        raise ConfigError(f"the joint map's columns {', '.join(cols)} cannot set its joints "
                          f"{', '.join(joints)} each: a compensated joint value could not be "
                          "written back into them (give each joint a column of its own)",
                          source=src)


def joint_cells(prog: Program, k: int, q_new, names, scales, jmap=None) -> dict:
    """The new cells ``{column: value}`` of row ``k`` for joint values ``q_new (n,)``
    (model units), in the CSV's units; through a joint map the controller's columns
    move by the least (minimum norm) change that gives the new values."""
    n = len(scales)
    row = prog.rows[k]
    out = {}
    mapped = []
    for i in range(n):
        nm = names[i] if names else None
        if jmap and nm in jmap.terms:
            mapped.append(i)
        else:
            out[prog.columns[i]] = q_new[i] / scales[i]
    if mapped:
        cols = sorted(jmap.columns)
        A = np.zeros((len(mapped), len(cols)))
        for r, i in enumerate(mapped):
            for c, coef in jmap.terms[names[i]]:
                A[r, cols.index(c)] += coef
        dv = np.array([(q_new[i] - prog.values[k, i]) / scales[i] for i in mapped])
        dc = np.linalg.lstsq(A, dv, rcond=None)[0]
        for c, d in zip(cols, dc):
            out[c] = float(row[prog.cells[c]]) + float(d)
    return out


def format_value(v: float) -> str:
    """A joint value as written (12 significant digits: far below any controller's)."""
    text = f"{v:.12g}"
    return "0" if text == "-0" else text


def program_text(prog: Program, rows: list, extra: list) -> str:
    """The CSV text: the program's columns then ``extra``, ``rows`` the cells of each."""
    out = io.StringIO()
    w = csv.writer(out, delimiter=prog.sep, lineterminator="\n")
    w.writerow(list(prog.head) + list(extra))
    w.writerows(rows)
    return out.getvalue()
