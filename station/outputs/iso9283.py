"""The figures of ``app.py accuracy`` (:mod:`station.accuracy`): pose accuracy and
repeatability as ISO 9283 defines them, measured at the station before and after the
calibration (docs/accuracy.md), as they are printed and written to the CSV.

A URDF robot calibrated by ``sm-markers`` at a station with a point instrument (a motion
capture, ``[mocap]``): the test cube that fits (:mod:`station.planning.iso_cube`; or
``--cube``), its five measuring poses P1..P5, n cycles of the *nominal program* (the
nominal model's inverse kinematics: what the robot's controller runs before the
calibration) and n cycles of the *compensated program* (``app.py compensate``'s values:
what it runs after), each measured by the instrument (:mod:`station.session.iso_run`).

The tool is the centre of the calibrated points on it (their mean), measured as the mean
of the points the instrument reads, and its orientation, where the points fix it, their
rigid fit. Both are compared in the instrument's frame with the commanded pose carried
there through the calibrated instrument frame (the parameter file's ``base_*``): the
frame's own error is in before and after alike. AP and RP as the standard writes them:
:mod:`calibration.iso9283`.

The station's own sensors do not give a position: a robot file's arm (``sm-distance``,
``sm-distance-tilt``, ...) has a draw-wire, one distance from a reference point, and the
tool inclinometer two angles against gravity; AP_P and RP_l need all three coordinates
of the tool. Such a parameter file (and AGEBOT's) is refused in one line.
"""
from __future__ import annotations

import math

import numpy as np

from calibration import iso9283
from calibration.compensation import rigid_fit
from calibration.errors import ConfigError

PROGRAMS = ("nominal", "compensated")
MAX_CYCLES = 1000


def why_not(doc: dict) -> str | None:
    """Why the test cannot be measured for a parameter file's content ``doc`` (its
    ``method``, ``robot`` and whether it is a URDF robot's), in one line; None where it
    can (a URDF robot calibrated by sm-markers)."""
    if doc.get("method") == "sm-markers" and "urdf" in doc:
        return None
    return (f"the accuracy test measures the tool's position with the station's point "
            f"instrument: a URDF robot calibrated by sm-markers at a station with a motion "
            f"capture ([mocap]); this file is {doc.get('robot')}'s by {doc.get('method')}, "
            "whose station measures a draw-wire's one distance and an inclinometer's two "
            "angles, not the tool's three coordinates (docs/accuracy.md)")


def check_file(doc: dict, path: str) -> None:
    """Refuse (one line) a parameter file the test cannot be measured for."""
    why = why_not(doc)
    if why:
        raise ConfigError(why, source=path)


def view_frame(robot, params: dict, xi_cal) -> tuple[np.ndarray, np.ndarray]:
    """``(x_view, frame (4, 4))``: the robot's parameters with the parameter file's values
    ``params`` (the calibrated instrument frame ``base_*`` too), and the base link in the
    instrument's frame, the calibrated model ``xi_cal`` (its ``base_*`` zero) carried
    there: where the commanded poses are compared with the attained ones."""
    x_view = robot.nominal.copy()
    for j, nm in enumerate(robot.param_names):
        if nm in params:
            x_view[j] = float(params[nm]["value"])
    q0 = np.zeros((1, robot.n_actuators))
    frame = robot.frames(q0, x_view)[0] @ np.linalg.inv(robot.frames(q0, xi_cal)[0])
    return x_view, frame


def parse_cube(text: str | None):
    """``--cube X,Y,Z,SIZE`` (mm, the base link frame) as ``(centre m, size m)``."""
    if not text:
        return None
    try:
        v = [float(t) for t in text.split(",")]
    except ValueError:
        v = []
    if len(v) != 4 or not all(math.isfinite(t) for t in v) or not 0 < v[3] <= 5000:
        raise ConfigError(f"--cube {text[:60]}: give X,Y,Z,SIZE in mm (the cube's centre in "
                          "the robot's base link frame and its edge, 0 < SIZE <= 5000)")
    return np.array(v[:3]) * 1e-3, v[3] * 1e-3


# -- what the readings say ---------------------------------------------------------------
def attained(tm, cube, points):
    """``(positions (c, 5, 3), angles (c, 5, 3) or None, commanded (5, 4, 4))`` of one
    program's ``points (c, 5, M, 3)`` (instrument frame): the tool's point (the mean of
    the points; NaN where one was not seen), its orientation's deviation about the base
    link frame's axes (where the compensation keeps the orientation), and the commanded
    poses in the instrument's frame."""
    F = tm.frame
    cmd = F @ cube.targets
    pos = points.mean(axis=2)
    if not tm.comp.orientation:
        return pos, None, cmd
    ang = np.full(pos.shape, np.nan)
    tool = tm.comp.tool_cal
    for c in range(points.shape[0]):
        for k in range(5):
            if np.all(np.isfinite(points[c, k])):
                E = rigid_fit(tm.points, points[c, k]) @ tool
                ang[c, k] = iso9283.deviation_angles(cmd[k, :3, :3], E[:3, :3], F[:3, :3])
    return pos, ang, cmd


# -- what is printed -----------------------------------------------------------------------
def table(res: dict) -> list[str]:
    """The standard's table: per pose AP_P and RP_l (mm) before and after, and the
    orientation's AP_a/b/c and RP_a/b/c (deg) where measured."""
    before, after = res["nominal"], res["compensated"]
    lines = ["pose   AP_P mm before    after   RP_l mm before    after",
             *(f"{b.name:<4} {b.ap * 1e3:15.3f} {a.ap * 1e3:8.3f} {b.rp * 1e3:14.3f} "
               f"{a.rp * 1e3:8.3f}" for b, a in zip(before, after))]
    ap = [np.mean([p.ap for p in rows]) * 1e3 for rows in (before, after)]
    rp = [np.mean([p.rp for p in rows]) * 1e3 for rows in (before, after)]
    lines.append(f"mean {ap[0]:15.3f} {ap[1]:8.3f} {rp[0]:14.3f} {rp[1]:8.3f}")
    if before[0].ap_abc is not None:
        lines.append("pose   AP_a,b,c deg before              after                "
                     "RP_a,b,c +-deg before         after")
        for b, a in zip(before, after):
            cells = [" ".join(f"{math.degrees(v):+8.4f}" for v in x)
                     for x in (b.ap_abc, a.ap_abc)]
            reps = [" ".join(f"{math.degrees(v):6.4f}" for v in x) for x in (b.rp_abc, a.rp_abc)]
            lines.append(f"{b.name:<4}   {cells[0]}  {cells[1]}   {reps[0]}  {reps[1]}")
    return lines


def summary(res: dict, cycles: int, predicted: float | None) -> list[str]:
    """What the table says: the factor AP improved by, RP before and after, the
    calibration's own prediction, and a note where n is below the standard's."""
    b = np.array([p.ap for p in res["nominal"]])
    a = np.array([p.ap for p in res["compensated"]])
    rb = np.mean([p.rp for p in res["nominal"]])
    ra = np.mean([p.rp for p in res["compensated"]])
    out = [f"AP_P: {np.sqrt(np.mean(b ** 2)) * 1e3:.3f} mm RMS over the five poses before, "
           f"{np.sqrt(np.mean(a ** 2)) * 1e3:.3f} mm after: "
           f"{np.sqrt(np.mean(b ** 2)) / max(np.sqrt(np.mean(a ** 2)), 1e-12):.1f} times "
           f"closer; RP_l {rb * 1e3:.3f} mm before, {ra * 1e3:.3f} mm after (a calibration "
           "does not change the robot's repeatability)"]
    if predicted is not None:
        out.append(f"the calibration's predicted error of the tool at the compensated poses: "
                   f"{predicted * 1e3:.3f} mm RMS (its std; AP after also holds the robot's "
                   "backlash in the one direction of approach, and the instrument's error)")
    if cycles < iso9283.CYCLES:
        rel = 1.0 / math.sqrt(2.0 * (cycles - 1))
        out.append(f"note: {cycles} cycles, fewer than the standard's {iso9283.CYCLES}: RP's "
                   f"S_l is estimated from {cycles} values (its own relative std about "
                   f"{rel:.0%})")
    return out


# -- the CSV -----------------------------------------------------------------------------
def csv_text(tm, cube, readings, names) -> str:
    """Every measured cycle: program, cycle, pose, the snapshot's time, the commanded and
    attained tool point (mm, instrument frame) and the distance between them, the
    orientation's deviation (deg) where measured, the points read (mm), the commanded
    and read joint values (``names``: the joints')."""
    M = tm.points.shape[0]
    head = ["program", "cycle", "pose", "t", "cmd_x_mm", "cmd_y_mm", "cmd_z_mm", "x_mm", "y_mm",
            "z_mm", "error_mm"]
    orient = tm.comp.orientation
    if orient:
        head += ["a_deg", "b_deg", "c_deg"]
    head += [f"m{j}_{c}_mm" for j in range(1, M + 1) for c in "xyz"]
    head += [f"{nm}_cmd" for nm in names] + [f"{nm}_read" for nm in names]
    lines = [",".join(head)]
    order = [iso9283.POINTS.index(p) for p in iso9283.CYCLE]
    for prog, r in readings.items():
        q = cube.q_nom if prog == "nominal" else cube.q_comp
        pos, ang, cmd = attained(tm, cube, r.points)
        for c in range(r.points.shape[0]):
            for k in order:
                e = float(np.linalg.norm(pos[c, k] - cmd[k, :3, 3]))
                row = [prog, str(c + 1), iso9283.POINTS[k], r.t[c][k]]
                row += [_num(v * 1e3) for v in cmd[k, :3, 3]] + [_num(v * 1e3) for v in pos[c, k]]
                row.append(_num(e * 1e3))
                if orient:
                    row += [_num(math.degrees(v), 9) for v in ang[c, k]]
                row += [_num(v * 1e3) for v in r.points[c, k].reshape(-1)]
                row += [_num(v, 9) for v in q[k]] + [_num(v, 9) for v in r.qm[c, k]]
                lines.append(",".join(row))
    return "\n".join(lines) + "\n"


def _num(v: float, decimals: int = 6) -> str:
    """mm to the nm; an angle (deg) and a joint's value (rad, m) to 1e-9: the figures
    rebuilt from the CSV are those of the readings, and the compensated program's values
    as exact as its solution (a CSV of another calibration is told apart by them)."""
    return f"{v:.{decimals}f}" if math.isfinite(v) else ""
