"""``app.py trace import``: a trace of a robot file from a CSV of joint values and
measurements (docs/robot-files.md, "Importing measurements").

One row per pose, a header row naming the columns (any order, extra columns
are errors):

====================  ==========================================================
``qm1 .. qmN``        actuator values, in the robot file's actuator units (required)
``x, y, z``           tool position in the base frame (sm-position, sm-full-pose)
``roll, pitch, yaw``  tool orientation, ``R = Rz(yaw) Ry(pitch) Rx(roll)`` (sm-full-pose)
``distance``          distance from the reference point (sm-distance, sm-distance-tilt)
``tilt_roll, tilt_pitch``  the tool inclinometer (sm-distance-tilt)
``group``             integer, poses sharing the tool position (sm-self-redundancy)
``use``               ``fit`` (default), ``validation`` (held out) or ``reference``
                      (the one row where the draw-wire was zeroed; distance methods)
====================  ==========================================================

Lengths are in ``--length-unit`` (``m`` default, or ``mm``), angles in
``--angle-unit`` (``rad`` default, or ``deg``); the trace holds SI units. Every
error names the CSV file and line.
"""
from __future__ import annotations

import hashlib
import math
from pathlib import Path

from calibration.errors import ConfigError
from calibration.methods import METHODS, check_kind
from calibration.robots import get_robot
from drivers.robot_file import load_robot_file
from station.recording.csv_columns import ANGLE, LENGTH, not_a_number, open_csv, parse_sigma
from station.recording.trace_writer import write_trace

# columns each method reads (besides qm and use), and the trace channel they form
COLUMNS = {"sm-position": {"position": ("x", "y", "z")},
           "sm-full-pose": {"pose": ("x", "y", "z", "roll", "pitch", "yaw")},
           "sm-distance": {"distance": ("distance",)},
           "sm-distance-tilt": {"distance": ("distance",), "tilt": ("tilt_roll", "tilt_pitch")},
           "sm-plane": {}, "sm-self-redundancy": {}}
ANGLES = {"roll", "pitch", "yaw", "tilt_roll", "tilt_pitch"}
USES = ("fit", "validation", "reference")


def import_csv(csv_path, robot_path, method: str, *, length_unit="m", angle_unit="rad",
               sigma: dict | None = None) -> tuple[dict, dict | None, list[dict]]:
    """``(header, reference, poses)`` of the trace (see module doc)."""
    src = str(csv_path)
    spec = load_robot_file(robot_path)
    robot = get_robot(spec)
    if method not in COLUMNS:
        raise ConfigError(f"method {method!r} cannot be imported for a robot file (known: "
                          f"{', '.join(COLUMNS)})", source=src)
    check_kind(method, robot)
    if length_unit not in LENGTH or angle_unit not in ANGLE:
        raise ConfigError(f"units must be {'/'.join(LENGTH)} and {'/'.join(ANGLE)}, not "
                          f"{length_unit!r}, {angle_unit!r}", source=src)
    raw, head, rows = open_csv(src)
    qcols = [f"qm{i}" for i in range(1, robot.n_actuators + 1)]
    need = qcols + [c for cols in COLUMNS[method].values() for c in cols]
    if method == "sm-self-redundancy":
        need.append("group")
    allowed = set(need) | {"use"}
    for c in head:
        if c not in allowed:
            raise ConfigError(f"column {c!r} is not one that {method} on {robot.name} reads "
                              f"(columns: {', '.join(need)}, optional use)", source=f"{src}:1")
    for c in need:
        if c not in head:
            raise ConfigError(f"missing column {c!r} ({method} on {robot.name} needs "
                              f"{', '.join(need)})", source=f"{src}:1")
    if len(set(head)) != len(head):
        raise ConfigError("a column is named twice", source=f"{src}:1")
    col = {c: head.index(c) for c in head}
    scale = {c: (ANGLE[angle_unit] if c in ANGLES else LENGTH[length_unit]) for c in need
             if c not in qcols and c != "group"}
    poses, reference = [], None
    for lineno, row in enumerate(rows, start=2):
        where = f"{src}:{lineno}"
        if not any(v.strip() for v in row):
            continue
        if len(row) != len(head):
            raise ConfigError(f"{len(row)} values for {len(head)} columns", source=where)

        def num(c):
            v = row[col[c]].strip()
            try:
                x = float(v)
            except ValueError:
                raise ConfigError(f"column {c}: {not_a_number(v)}", source=where) from None
            if not math.isfinite(x):
                raise ConfigError(f"column {c}: {v!r} is not finite", source=where)
            return x

        use = row[col["use"]].strip() if "use" in col else "fit"
        use = use or "fit"
        if use not in USES:
            raise ConfigError(f"column use: {use!r} is not one of {', '.join(USES)}", source=where)
        qm = [num(c) for c in qcols]
        for i, (v, (lo, hi)) in enumerate(zip(qm, robot.limits), start=1):
            if not lo <= v <= hi:
                raise ConfigError(f"column qm{i}: {v!r} is outside the joint's limits "
                                  f"[{float(lo)!r}, {float(hi)!r}] of {Path(str(robot_path)).name} "
                                  f"(actuator units: the robot file's limits and k)",
                                  source=where)
        if use == "reference":
            if METHODS[method].reference is None:
                raise ConfigError(f"{method} has no reference row", source=where)
            if reference is not None:
                raise ConfigError("a second reference row", source=where)
            reference = {"role": METHODS[method].reference, "qm": qm}
            continue
        rec = {"index": len(poses), "qm": qm}
        for ch, cols in COLUMNS[method].items():
            vals = [num(c) * scale[c] for c in cols]
            for c, v in zip(cols, vals):
                _sensor_range(c, v, where, length_unit, angle_unit)
            rec[ch] = vals[0] if ch == "distance" else vals
        if method == "sm-self-redundancy":
            g = row[col["group"]].strip()
            if not g.lstrip("-").isdigit():
                raise ConfigError(f"column group: {g!r} is not an integer", source=where)
            rec["group"] = int(g)
        if use == "validation":
            rec["use"] = "validation"
        poses.append(rec)
    if not poses:
        raise ConfigError("no poses (one row per pose after the header)", source=src)
    if METHODS[method].reference and reference is None:
        raise ConfigError(f"{method} needs the reference row (use = reference): the actuator "
                          f"values where the draw-wire was zeroed", source=src)
    header = {"robot": robot.name, "robot_file": dict(spec.source), "method": method,
              "nominal": robot.as_dict(robot.nominal),
              "station": {"imported_from": {"file": Path(src).name,
                                            "sha256": hashlib.sha256(raw).hexdigest()},
                          "units": {"length": length_unit, "angle": angle_unit}}}
    if sigma:
        header["sigma"] = sigma
    return header, reference, poses


# What the channels' sensors can read (SI): beyond it a reading is in another unit.
DISTANCE_READS = (-0.01, 100.0)     # a draw-wire zeroed at the reference, m
POSITION_READS = 100.0              # a tracker's range, m
TILT_READS = (math.pi * (1 + 1e-9), math.pi / 2 * (1 + 1e-9))  # an inclinometer's roll, pitch
ANGLE_READS = math.pi * (1 + 1e-9)  # roll, pitch, yaw, rad


def _sensor_range(col: str, v: float, where: str, length_unit: str, angle_unit: str) -> None:
    """A reading (SI) no sensor of its channel reads is an error naming its column
    and the likely unit (the trace would only be refused later, by line number)."""
    deg = " (are they in degrees? --angle-unit deg)" if angle_unit == "rad" else ""
    mm = " (are they in mm? --length-unit mm)" if length_unit == "m" else ""
    if col == "distance" and not DISTANCE_READS[0] <= v <= DISTANCE_READS[1]:
        raise ConfigError(f"column distance: {v:.6g} m is not a distance a draw-wire zeroed "
                          f"at the reference reads ({DISTANCE_READS[0]:g} to "
                          f"{DISTANCE_READS[1]:g} m){mm if v > 0 else ''}", source=where)
    if col in ("x", "y", "z") and abs(v) > POSITION_READS:
        raise ConfigError(f"column {col}: {v:.6g} m is beyond a tracker's range "
                          f"({POSITION_READS:g} m){mm}", source=where)
    if col in ("tilt_roll", "tilt_pitch") and abs(v) > TILT_READS[col == "tilt_pitch"]:
        raise ConfigError(f"column {col}: {v:.6g} rad is beyond what a dual-axis "
                          f"inclinometer reads (roll +-180 deg, pitch +-90 deg){deg}",
                          source=where)
    if col in ("roll", "pitch", "yaw") and abs(v) > ANGLE_READS:
        raise ConfigError(f"column {col}: {v:.6g} rad is not an angle of -pi..pi{deg}",
                          source=where)


# --sigma channels of each method: the solver's row channels and the trace's vector ones
SIGMA_CHANNELS = {"sm-position": ("position", "x", "y", "z"),
                  "sm-full-pose": ("pose", "x", "y", "z", "roll", "pitch", "yaw"),
                  "sm-distance": ("distance",),
                  "sm-distance-tilt": ("distance", "tilt", "roll", "pitch"),
                  "sm-plane": (), "sm-self-redundancy": ()}


def import_command(args) -> str:
    """``app.py trace import``: write the trace atomically; returns a summary line."""
    from drivers.urdf_file import is_urdf

    if is_urdf(args.robot) or args.method == "sm-markers":
        if not is_urdf(args.robot):
            raise ConfigError(f"sm-markers takes a URDF robot (--robot FILE.urdf --base-link B "
                              f"--tip-link T), not {args.robot}")
        if args.method != "sm-markers":
            raise ConfigError(f"a URDF robot's measurements are imported as sm-markers (points "
                              f"on the tool), not {args.method}")
        from station.recording.import_markers import import_markers_command

        return import_markers_command(args)
    for opt in ("base_link", "tip_link", "validation", "joint_map", "ignore_columns"):
        if getattr(args, opt, None):
            raise ConfigError(f"--{opt.replace('_', '-')} is for a URDF robot (sm-markers); "
                              f"{args.robot} is a robot file")
    sigma = parse_sigma(args.sigma, SIGMA_CHANNELS.get(args.method, ()))
    header, reference, poses = import_csv(args.csv, args.robot, args.method,
                                          length_unit=args.length_unit,
                                          angle_unit=args.angle_unit, sigma=sigma)
    write_trace(args.out, header, reference, poses)
    return f"trace written to {args.out} ({len(poses)} poses of {header['robot']}, {args.method})"
