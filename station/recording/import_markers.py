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

import hashlib
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from calibration.errors import ConfigError
from calibration.methods.sm_markers import (marker_names, register, scale_and_mirror,
                                           tip_frames)
from calibration.robots import get_robot
from calibration.robots.serial import rpy_of
from drivers.urdf_file import load_urdf
from station.recording.csv_columns import ANGLE, LENGTH
from station.recording.marker_csv import MarkerReader

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
    reader = MarkerReader(robot, spec, length_unit, angle_unit, jmap, ignore)
    poses: list = []
    files = [(str(csv_path), "fit")] + ([(str(validation), "validation")] if validation else [])
    digests = {}
    for path, use in files:
        before = len(poses)
        raw = reader.read(path, use, poses)
        if len(poses) == before:
            raise ConfigError("no poses (one row per pose after the header)", source=path)
        digests[path] = hashlib.sha256(raw).hexdigest()
    reader.check_prismatic_units(poses, str(csv_path))
    check_pose_set(poses, reader.lines, str(csv_path))
    fit = [p for p in poses if p.get("use", "fit") == "fit"]
    held = [p for p in poses if p.get("use") == "validation"]
    nominal = start_values(robot, *pose_arrays(spread(fit)), str(csv_path),
                           held=(*pose_arrays(spread(held)), str(validation)) if held else None)
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
    return Imported(header, poses, reader.warnings + reader.limit_warnings())


#: the fewest fit poses an import takes (the instrument's frame needs three)
MIN_FIT_POSES = 3


#: poses the start values and the import's checks are made from at most (spread over the
#: rows in their order: 100 000 rows imported in 32 s, two thirds of it registering them)
START_POSES = 2000


def spread(poses: list) -> list:
    """At most :data:`START_POSES` of ``poses``, spread over them in order."""
    if len(poses) <= START_POSES:
        return poses
    return [poses[int(k)] for k in np.linspace(0, len(poses) - 1, START_POSES)]


def pose_arrays(poses) -> tuple[np.ndarray, np.ndarray]:
    """``(qm (n, N), points (n, M, 3))`` of pose records, nan where a point is not seen."""
    qm = np.array([p["qm"] for p in poses], dtype=float)
    pts = np.array([[[math.nan] * 3 if c is None else c for c in p["markers"]] for p in poses],
                   dtype=float)
    return qm, pts


def check_pose_set(poses: list, lines: list[str], where: str) -> None:
    """What the rows must be as a whole: at least :data:`MIN_FIT_POSES` fit rows, every
    point seen in a fit row (its place on the tool is learnt there), no row twice (an
    export written twice would count every pose twice and shrink every std by 0.7), and
    no held-out row that is a fit row (a held-out pose is one the fit has not seen)."""
    fit = [k for k, p in enumerate(poses) if p.get("use", "fit") == "fit"]
    if len(fit) < MIN_FIT_POSES:
        raise ConfigError(f"{len(fit)} fit pose(s): sm-markers needs poses in at least "
                          f"{MIN_FIT_POSES} configurations (and eq. 60's count to identify "
                          "the robot: app.py batch says how many)", source=where)
    n = len(poses[0]["markers"])
    for j in range(n):
        if all(poses[k]["markers"][j] is None for k in fit):
            seen = next((lines[k] for k, p in enumerate(poses) if p["markers"][j] is not None),
                        None)
            raise ConfigError(f"point {j + 1} is never seen in the fit rows" + (
                f" (only held out, first at {seen})" if seen else "") + ": its place on the "
                "tool cannot be learnt; --ignore-columns its columns, or fit rows that see it",
                source=where)
    first: dict = {}
    for k, p in enumerate(poses):
        key = (tuple(p["qm"]), tuple(tuple(c) if c else None for c in p["markers"]))
        if key in first:
            a, use = first[key], p.get("use", "fit")
            both = poses[a].get("use", "fit")
            what = ("a held-out row is a fit row: a held-out pose must be one the fit has "
                    "not seen (is --validation the fit file, or an export of the same rows?)"
                    if use != both else "the same pose twice (every value equal): an export "
                    "written twice? each row counts as a pose; remove the copies")
            same = lines[a].rsplit(":", 1)[0] == lines[k].rsplit(":", 1)[0]
            other = f"line {lines[a].rsplit(':', 1)[1]}" if same else lines[a]
            raise ConfigError(f"repeats {other}: {what}", source=lines[k])
        first[key] = k


def start_values(robot, qm, pts, where: str, held=None) -> dict:
    """The nominal of the trace: the instrument frame and the points on the tool that
    best explain the fit rows with the robot at its URDF values; refuses readings
    that a unit, a mirror or a wrong joint column makes inconsistent with the robot,
    and held-out rows ``held = (qm, points, file)`` in another unit or frame than the
    fit rows (:func:`check_held_out`)."""
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
    R, t, u, median = register(robot, qm, pts, xi)
    if held is not None and len(held[0]) >= MIN_FIT_POSES:   # fewer: the gate judges them
        check_held_out(robot, xi, (R, t, u), max(median, FOLLOW_SHARE * spread), *held)
    roll, pitch, yaw = rpy_of(R[None])[0]
    out = {"base_x": float(t[0]), "base_y": float(t[1]), "base_z": float(t[2]),
           "base_roll": float(roll), "base_pitch": float(pitch), "base_yaw": float(yaw)}
    out.update(zip(marker_names(len(u)), (float(v) for v in u.reshape(-1))))
    return out


def check_held_out(robot, xi, placement, bar: float, qm, pts, where: str) -> None:
    """Held-out rows (three or more) must be in the fit rows' unit and instrument frame:
    their median distance from where the fit rows' placement ``(R, t, u)`` puts the points
    at most ``bar`` (the larger of the fit rows' own median and :data:`FOLLOW_SHARE` of their
    spread); else one line saying which (a unit: they move another distance than the
    tool; a frame: they are shifted or turned as a whole)."""
    R, t, u = placement
    T = tip_frames(robot, qm, xi)
    pred = (T[:, None, :3, 3] + np.einsum("sij,kj->ski", T[:, :3, :3], u)) @ R.T + t
    seen = np.all(np.isfinite(pts), axis=2)
    d = float(np.median(np.linalg.norm(pts[seen] - pred[seen], axis=1)))
    if d <= bar:
        return
    scale = scale_and_mirror(robot, qm, pts, xi)[0] if len(qm) >= MIN_FIT_POSES else 1.0
    why = (f"they move {scale:.3g} times as far as the robot's tool: another unit "
           "(--length-unit applies to both files)" if not 1 / 3 < scale < 3 else
           "another instrument frame (moved, or another day's calibration of the "
           "instrument) or another robot")
    raise ConfigError(f"the held-out rows' points lie {d * 1e3:.4g} mm (median) from where the "
                      f"fit rows' instrument frame puts them ({bar * 1e3:.3g} mm at most): {why}; "
                      "held-out rows must be measured in the fit rows' frame and unit",
                      source=where)


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
