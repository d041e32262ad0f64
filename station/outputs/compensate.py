"""``app.py compensate PARAMS.json --program IN.csv --out OUT.csv``: a program the
nominal controller runs, rewritten so that the calibrated robot reaches its targets
(docs/compensation.md).

Each row's target is where the nominal model (the parameter file's ``nominal`` values,
the robot's own where it gives none) puts the tool at the row's joint values; the
compensated values bring the calibrated model there, from the row's values, within the
joint limits (:mod:`calibration.compensation`). What is compensated is what the
calibration determines (:func:`setup`): a robot file's tool point, and its
orientation where the method measured it (``sm-full-pose``); a URDF robot's points on
the tool (``sm-markers``): their centre, and the tool's orientation where three or more
of them span a plane, in the robot's base link frame (the instrument's frame left
out of both models); AGEBOT's arm: its point and phi; its wrist: the orientation.

The program's CSV is read and written by :mod:`station.recording.program_csv`; the
output has its columns and units plus ``residual_mm`` (``residual_deg`` where the
orientation is compensated) and ``status``; a target out of reach keeps the row's
values and is named (``unreachable: ...``) there and on stderr.
"""
from __future__ import annotations

import math
import sys
from dataclasses import dataclass

import numpy as np

from calibration.compensation import (
    ArmCompensation,
    SerialCompensation,
    WristCompensation,
    rigid_fit,
    spans_plane,
)
from calibration.errors import CalibrationError, ConfigError
from station.recording import program_csv as pc
from station.recording.csv_columns import ANGLE, LENGTH
from station.recording.marker_csv import LIMIT_SLACK, LIMIT_SLACK_MIN


@dataclass
class Setup:
    """What a parameter file compensates: the robot, its compensation
    (:mod:`calibration.compensation`), the joints' names (a URDF's; empty: qm1..qmN),
    kinds (``"R"``, ``"P"``; None: actuator units), the actuator bounds a nominal row
    is judged by, and ``what`` the targets are, in words."""

    robot: object
    comp: object
    names: tuple
    kinds: tuple
    limits: np.ndarray | None
    what: str
    urdf_joints: tuple = ()


#: the methods that measure the tool in the robot's base frame (a tracker placed there);
#: the others' frame is their own (a reference point, a base origin, a plane, an
#: instrument's room): the base frame is left out of both models
BASE_FRAME_METHODS = ("sm-position", "sm-full-pose")
#: AGEBOT's arm: what places its rail in the base frame (the base offset, the rail's zero)
ARM_FRAME = ("theta0", "a0", "q1_off")


def _zero(robot, vectors, names) -> None:
    for nm in names:
        for x in vectors:
            x[robot.index(nm)] = 0.0


def _translation(p) -> np.ndarray:
    T = np.eye(4)
    T[:3, 3] = p
    return T


def setup(doc: dict, path: str) -> Setup:
    """The :class:`Setup` of a parameter file's content ``doc`` (read and checked)."""
    from calibration.methods.sm_markers import FRAME_PARAMS, marker_count, marker_names
    from calibration.robots import get_robot
    from drivers.robot_file import spec_from_source

    params, method = doc["parameters"], doc["method"]
    if "robot_file" in doc:
        robot = get_robot(spec_from_source(doc["robot_file"], f"{path}: robot_file"))
    else:
        robot = get_robot(doc["robot"])

    def vector(key):
        x = robot.nominal.copy()
        for j, nm in enumerate(robot.param_names):
            if nm in params:
                x[j] = float(params[nm][key])
        return x

    x_nom, x_cal = vector("nominal"), vector("value")
    x_pred = x_cal.copy()
    own_frame = method not in BASE_FRAME_METHODS     # the method's frame is not the robot's
    if robot.name == "agebot-sm" and "robot_file" not in doc:
        where = ""
        if own_frame:
            _zero(robot, (x_nom, x_cal), ARM_FRAME)
            where = (f", in the rail's frame ({', '.join(ARM_FRAME)} place the rail in "
                     f"{method}'s frame, not the controller's: left out of both models)")
        q_lo, q_hi = robot.joint_limits.T
        k, off = x_nom[4:8], x_nom[0:4]
        a, b = (q_lo - off) / k, (q_hi - off) / k
        return Setup(robot, ArmCompensation(robot, x_nom, x_cal, x_pred), (), (None,) * 4,
                     np.column_stack([np.minimum(a, b), np.maximum(a, b)]),
                     "the tool point and phi (the arm's four joints set both)" + where)
    if robot.kind == "parallel-wrist":
        return Setup(robot, WristCompensation(robot, x_nom, x_cal), (), (None,) * 3, None,
                     "the platform's orientation (alpha, beta, gamma)")
    n = robot.n_actuators
    limits = np.array(robot.limits, dtype=float)
    joints = robot.spec.joints
    for i, jt in enumerate(joints):
        if getattr(jt, "continuous", False):
            limits[i] = (-math.inf, math.inf)
    if not hasattr(robot, "calibrated_origins"):          # a robot file
        full = method == "sm-full-pose" and n >= 6
        what = ("the tool frame's point and orientation (sm-full-pose measures both)" if full
                else f"the tool point ({method} " + ("measures no orientation)" if n >= 6 else
                                                     f"on a {n}-joint arm)"))
        if own_frame:
            _zero(robot, (x_nom, x_cal), [nm for nm in robot.param_names
                                          if nm.startswith("base_")])
            what += (f", in joint 1's frame (the base frame is {method}'s, not the "
                     "controller's: left out of both models)")
        comp = SerialCompensation(robot, x_nom, x_cal, orientation=full, limits=limits,
                                  xi_pred=x_pred)
        return Setup(robot, comp, (), (None,) * n, limits, what)
    names = marker_names(marker_count(params))
    M = len(names) // 3
    if not M:
        raise ConfigError(f"{method} of a URDF robot: no points on the tool in the file",
                          source=path)
    u_nom = np.array([float(params[nm]["nominal"]) for nm in names]).reshape(M, 3)
    u_cal = np.array([float(params[nm]["value"]) for nm in names]).reshape(M, 3)
    x_pred = np.r_[x_pred, u_cal.reshape(-1)]
    _zero(robot, (x_nom, x_cal), FRAME_PARAMS)   # the base link's frame, not the instrument's
    full = spans_plane(u_nom) and n >= 6
    tool_nom = _translation(u_nom.mean(axis=0))     # the nominal's centre: E maps it to the
    tool_cal = (rigid_fit(u_nom, u_cal) @ tool_nom  # calibrated points' centre, turned as
                if full else _translation(u_cal.mean(axis=0)))  # the points are
    comp = SerialCompensation(robot, x_nom, x_cal, tool_nom=tool_nom,
                              tool_cal=tool_cal, orientation=full, limits=limits,
                              xi_pred=x_pred, point_params=[names[3 * j:3 * j + 3]
                                                           for j in range(M)])
    what = (f"the tool's point (the centre of its {M} points) and orientation (the points "
            "fix both)" if full else
            f"the tool point (the centre of its {M} point(s); "
            + ("they do not fix its orientation)" if n >= 6 else f"a {n}-joint arm)"))
    return Setup(robot, comp, robot.spec.joint_names, tuple(jt.kind for jt in joints), limits,
                 what + f", in the frame of the base link {robot.spec.base_link}",
                 _all_urdf_joints(robot))


def _all_urdf_joints(robot) -> tuple:
    """Every joint's name in the URDF's text (those outside the chain are refused as
    columns)."""
    import xml.etree.ElementTree as ET

    try:
        root = ET.fromstring(robot.spec.source["text"])
    except (ET.ParseError, KeyError, TypeError):
        return ()
    return tuple(j.get("name") for j in root.iter("joint") if j.get("name"))


def _scales(s: Setup, args, src: str) -> list:
    au, lu = getattr(args, "angle_unit", None), getattr(args, "length_unit", None)
    if not s.names:
        for flag, v in (("--angle-unit", au), ("--length-unit", lu),
                        ("--joint-map", getattr(args, "joint_map", None))):
            if v is not None:
                raise ConfigError(f"{flag} is for a URDF robot's joint columns; {s.robot.name}'s "
                                  f"columns qm1..qm{len(s.kinds)} are in its actuator units",
                                  source=src)
        return [1.0] * len(s.kinds)
    return [ANGLE[au or "rad"] if k == "R" else LENGTH[lu or "m"] for k in s.kinds]


def _unit(s: Setup, i: int, args) -> str:
    if s.kinds[i] is None:
        return "actuator units"
    return (args.angle_unit or "rad") if s.kinds[i] == "R" else (args.length_unit or "m")


def _label(s: Setup, i: int) -> str:
    return s.names[i] if s.names else f"qm{i + 1}"


def check_rows(s: Setup, prog, args) -> list[str]:
    """Refuse a row far outside the nominal robot's limits (naming the unit); a row a
    little beyond (an encoder at its end stop) is a warning, one per joint and side."""
    out, beyond = [], {}
    if s.limits is None:
        return out
    for i, (lo, hi) in enumerate(s.limits):
        if not math.isfinite(hi - lo):
            continue
        v = prog.values[:, i]
        kind = s.kinds[i]
        slack = max(LIMIT_SLACK * (hi - lo), LIMIT_SLACK_MIN.get(kind, 0.0))
        si = "rad" if kind == "R" else "m" if kind == "P" else "actuator units"
        for k in np.flatnonzero((v < lo) | (v > hi)):
            side, lim = ("lower", lo) if v[k] < lo else ("upper", hi)
            by = abs(v[k] - lim)
            if by > slack:
                hint = ("are the joint values in degrees? (--angle-unit deg)" if kind == "R"
                        and args.angle_unit in (None, "rad") and abs(v[k]) > 2 * math.pi
                        else "check the column's unit, sign and zero"
                        + (" (--joint-map)" if s.names else ""))
                raise ConfigError(f"column {prog.columns[i]}: {v[k]:.6g} {si} is far outside "
                                  f"the joint's limits [{lo:.6g}, {hi:.6g}] {si} of the nominal "
                                  f"robot: {hint}", source=prog.where(k))
            seen = beyond.setdefault((i, side), [0, 0.0, "", lim])
            seen[0] += 1
            if by > seen[1]:
                seen[1], seen[2] = by, prog.where(k)
    for (i, side), (count, most, where, lim) in beyond.items():
        si = "rad" if s.kinds[i] == "R" else "m" if s.kinds[i] == "P" else "actuator units"
        out.append(f"{_label(s, i)}: {count} row(s) beyond its {side} limit {lim:.6g} {si}, by "
                   f"up to {most:.3g} {si} at {where}; kept (compensated within the limits)")
    return out


def _targets(s: Setup, prog):
    try:
        return s.comp.targets(prog.values)
    except CalibrationError:                  # the wrist: a row where it cannot assemble
        for k in range(len(prog.values)):
            try:
                s.comp.targets(prog.values[k:k + 1])
            except CalibrationError as e:
                raise ConfigError(f"the nominal wrist (the parameter file's nominal) cannot "
                                  f"assemble at these actuator values: {e}",
                                  source=prog.where(k)) from None
        raise


def _reason(s: Setup, sol, args, scales) -> str:
    if sol.joint is not None:
        i = sol.joint
        lo, hi = s.comp.limits[i]
        side, lim = ("upper", hi) if "upper" in sol.reason else ("lower", lo)
        text = (f"{_label(s, i)} would pass its {side} limit {lim / scales[i]:.6g} "
                f"{_unit(s, i, args)}")
    else:
        text = sol.reason
    if math.isfinite(sol.best):
        text += f", {sol.best * 1e3:.3g} mm from the target at best"
    if math.isfinite(sol.position):
        text += f"; the row kept as it was, {sol.position * 1e3:.3g} mm from the target"
    elif math.isfinite(sol.angle):
        text += f"; the row kept as it was, {math.degrees(sol.angle):.3g} deg from the target"
    return text


def main(args) -> int:
    """The command (module doc): prints the summary, warnings to stderr."""
    from drivers.atomic import check_outputs, write_atomic
    from station.outputs.params_file import check_usable, read_params
    from station.recording.joint_map import load_joint_map

    check_outputs((args.out, "the compensated program"),
                  inputs=tuple(p for p in (args.params, args.program, args.joint_map) if p))
    doc = read_params(args.params)
    check_usable(doc, args.params)
    s = setup(doc, args.params)
    scales = _scales(s, args, args.program)
    jmap = None
    if args.joint_map:
        jmap = load_joint_map(args.joint_map, s.names)
        pc.check_map_writable(jmap, args.joint_map)
    prog = pc.read_program(args.program, s.names, scales, jmap,
                           [j for j in s.urdf_joints if j not in s.names])
    warn = check_rows(s, prog, args)
    targets = _targets(s, prog)
    sols = [s.comp.solve(prog.values[k], targets[k]) for k in range(len(targets))]
    has_pos = not isinstance(s.comp, WristCompensation)
    extra = (["residual_mm"] if has_pos else []) + (
        ["residual_deg"] if s.comp.orientation else []) + ["status"]
    rows, moved, unreachable = [], {}, []
    for k, sol in enumerate(sols):
        row = list(prog.rows[k])
        if sol.ok:
            for c, v in pc.joint_cells(prog, k, sol.qm, s.names, scales, jmap).items():
                ci = prog.cells[c]
                moved.setdefault(c, []).append(v - float(row[ci]))
                row[ci] = pc.format_value(v)
            status = "ok"
        else:
            status = f"unreachable: {_reason(s, sol, args, scales)}"
            unreachable.append(f"{prog.where(k)} (row {k + 1}): {status}")
        if has_pos:
            row.append(f"{sol.position * 1e3:.6f}")
        if s.comp.orientation:
            row.append(f"{math.degrees(sol.angle):.6f}")
        rows.append(row + [status])
    write_atomic(args.out, pc.program_text(prog, rows, extra).encode("utf-8"))
    for w in warn + unreachable:
        print(f"warning: {w}", file=sys.stderr)
    for line in summary(s, doc, args, prog, sols, moved, scales, jmap):
        print(line)
    return 0


def summary(s: Setup, doc, args, prog, sols, moved, scales, jmap=None) -> list[str]:
    """The lines printed: rows, compensated, unreachable; the correction applied (RMS per
    joint column, the CSV's units); the calibration's predicted error at the targets
    and the calibrated model's own residual."""
    ok = [sol for sol in sols if sol.ok]
    lines = [(f"compensated program written to {args.out} ({len(sols)} rows: {len(ok)} "
              f"compensated, {len(sols) - len(ok)} unreachable)"),
             (f"targets: {s.what}; from the nominal model of {args.params} ({doc['robot']}, "
              f"{doc['method']})")]
    if moved:
        units = {}
        for i in range(len(scales)):          # a joint map's column: its joints' unit
            for c in ([prog.columns[i]] if prog.columns[i] in prog.cells else
                      [c for c, _ in jmap.terms[s.names[i]]]):
                units.setdefault(c, _unit(s, i, args))
        parts = [f"{c} {math.sqrt(np.mean(np.square(d))):.4g} {units.get(c, '')}".rstrip()
                 for c, d in moved.items()]
        lines.append("correction applied (RMS over the compensated rows): " + ", ".join(parts))
    if ok:
        q = np.array([sol.qm for sol in ok])
        cov = doc["covariance"]
        sp, sa = s.comp.predicted(q, list(cov["names"]), np.asarray(cov["matrix"], float))
        pred = []
        if np.isfinite(sp).any():
            pred.append(f"{math.sqrt(np.nanmean(sp ** 2)) * 1e3:.3g} mm RMS")
        if np.isfinite(sa).any():
            pred.append(f"{math.degrees(math.sqrt(np.nanmean(sa ** 2))):.3g} deg RMS "
                        "(orientation)")
        own = []
        if np.isfinite([sol.position for sol in ok]).all():
            own.append(f"{max(sol.position for sol in ok) * 1e3:.2g} mm")
        if s.comp.orientation:
            own.append(f"{math.degrees(max(sol.angle for sol in ok)):.2g} deg")
        lines.append("predicted remaining error: " + ", ".join(pred)
                     + " (the calibration's std of the tool at the compensated values); "
                     "the calibrated model's own residual at most " + ", ".join(own))
    return lines
