"""Checks that catch a mis-configured station before any pose is recorded.

:func:`check_config` (before any motion): the devices the method reads are in
the station config (a missing ``[drawwire]`` with sm-distance-tilt, an
inclinometer without the axes the method needs).

:func:`check_reference` (at the reference, before its record): the draw-wire
reads about zero right after it was zeroed, and a small test move (about 3 cm and
3 degrees of the last link, by the nominal model) changes the draw-wire's reading
by about the distance moved and the inclinometer's tilt by about the angle turned,
with the same sign. A swapped Modbus word order (readings of -1329 m), a wrong
``metres_per_count`` or a flipped inclinometer sign fail here, with the config key
to check, instead of producing a confident wrong calibration. "About" is wide on
purpose: the true robot may differ from the nominal by +-40 % in its gear ratios.

:func:`check_wrist` (the wrist, before its scout round is planned): a test move of
+3 degrees in roll and -2 in pitch (nominal model) must turn the inclinometer's roll
and pitch each the same way (a flipped sign, swapped axes) and not by a wildly other
amount (a unit: within a factor of 10; a far-off wrist's nominal predicts its
turns within a factor of 3).
"""
from __future__ import annotations

import math

import numpy as np

from calibration.errors import CalibrationError, ConfigError
from station.session.joint_directions import (MOVE_M, SLACK_M, check_directions,
                                               position_jacobian, read_at_rest)

# inclinometer channels each session method reads (station config [inclinometer.axes])
INCLINOMETER_AXES = {"sm-distance-tilt": ("tilt",), "pm-tilt": ("roll", "pitch"),
                     "pm-ik": ("roll", "pitch", "yaw"), "pm-fk": ("roll", "pitch", "yaw")}
ZERO_TOL_M = 1e-3           # |reading| right after zeroing
RATIO = (0.4, 2.5)          # measured / nominal change of a test move
WRIST_RATIO = (0.1, 10.0)   # the wrist's nominal can be far off (its sign is the check)
TURN_RAD = math.radians(3.0)
SLACK_RAD = math.radians(0.3)


def check_config(config, method: str) -> None:
    """Refuse a station config that lacks a device or an axis ``method`` reads (a robot
    file's arm reads its tool inclinometer's roll and pitch for sm-distance-tilt)."""
    from calibration.methods import METHODS

    if "distance" in METHODS[method].channels and config.drawwire is None:
        raise ConfigError(f"{method} measures distances, and the station config has no "
                          "[drawwire] section (the draw-wire's link, scale and word order)",
                          source=config.source, key="drawwire")
    if method == "sm-markers" and getattr(config, "mocap", None) is None:
        raise ConfigError("sm-markers measures points on the tool with a point instrument, and "
                          "the station config has no [mocap] section (the motion capture's "
                          "link, the labels of the points, its measuring volume)",
                          source=config.source, key="mocap")
    axes = INCLINOMETER_AXES.get(method, ())
    if method == "sm-distance-tilt" and getattr(config, "spec", None) is not None:
        axes = ("roll", "pitch")
    if axes and config.inclinometer is None:
        raise ConfigError(f"{method} reads the inclinometer ({', '.join(axes)}), and the "
                          "station config has no [inclinometer] section",
                          source=config.source, key="inclinometer")
    missing = [a for a in axes if config.inclinometer is not None
               and a not in config.inclinometer.axes]
    if missing:
        raise ConfigError(f"{method} reads the inclinometer's {', '.join(missing)}: map "
                          f"{' and '.join(missing)} in [inclinometer.axes]",
                          source=config.source, key="inclinometer.axes")


def _test_move(robot, xi, q0, distance: bool, tilt: bool) -> np.ndarray:
    """Actuator step of about MOVE_M (distance) and TURN_RAD of phi (tilt), nominal model."""
    n = robot.n_actuators
    h = 1e-4
    X0 = robot.fk(np.atleast_2d(q0), xi)[0]
    J = np.array([(robot.fk(np.atleast_2d(q0 + h * np.eye(n)[i]), xi)[0] - X0) / h
                  for i in range(n)])                      # row i: d(x, y, z, phi)/dq_i
    dq = np.zeros(n)
    used = set()
    if tilt:
        i = int(np.argmax(np.abs(J[:, 3])))
        dq[i] = TURN_RAD / J[i, 3]
        used.add(i)
    if distance:
        speed = np.linalg.norm(J[:, :3], axis=1)
        speed[list(used)] = 0.0
        i = int(np.argmax(speed))
        dq[i] = MOVE_M / speed[i]
    return dq


def check_reference(session) -> str | None:
    """At the reference, before its record: zero the draw-wire, read, make a small
    test move, read, move back; then the joints' directions
    (:func:`station.session.joint_directions.check_directions`).
    Raises ConfigError naming what to check; returns the findings in words (None when
    the method reads neither distance nor tilt)."""
    rig, robot, cfg = session.rig, session.robot, session.config
    distance = "distance" in session.info.channels and rig.drawwire is not None
    tilt = session.method == "sm-distance-tilt"
    if not (distance or tilt) or not rig.can_move:
        return None
    if session.serial:
        return check_serial_reference(session, distance, tilt)
    if robot.name != "agebot-sm":
        return None
    q0 = np.array(rig.qm(), dtype=float)
    if distance:
        rig.zero_drawwire()
    r0 = read_at_rest(rig)
    problems = []
    if distance and abs(r0["distance"]) > ZERO_TOL_M:
        problems.append(f"the draw-wire reads {r0['distance']:.6g} m right after it was zeroed "
                        f"at the reference (expected about 0): check drawwire.offset_m "
                        f"({cfg.drawwire.offset_m:g}) and drawwire.word_order "
                        f"({cfg.drawwire.word_order})")
    dq = _test_move(robot, session.nominal, q0, distance, tilt)
    rig.move_to(q0 + dq)
    try:
        r1 = read_at_rest(rig)
    finally:
        rig.move_to(q0)
    X0, X1 = robot.fk(np.vstack([q0, q0 + dq]), session.nominal)
    said = []
    if distance:
        want = float(np.linalg.norm(X1[:3] - X0[:3]))
        got = r1["distance"] - r0["distance"]
        said.append(f"draw-wire {got * 100:.2f} cm for {want * 100:.2f} cm")
        if not RATIO[0] * want - SLACK_M <= got <= RATIO[1] * want + SLACK_M:
            problems.append(f"a test move of {want * 100:.1f} cm (nominal model) changed the "
                            f"draw-wire's reading by {got:.6g} m: check drawwire.word_order "
                            f"({cfg.drawwire.word_order}) and drawwire.metres_per_count "
                            f"({cfg.drawwire.metres_per_count:g})")
    if tilt:
        want = float(X1[3] - X0[3])
        got = r1["tilt"] - r0["tilt"]
        said.append(f"tilt {math.degrees(got):.2f} deg for {math.degrees(want):.2f} deg")
        if got * want < 0 and abs(got) > SLACK_RAD:
            problems.append(f"a test move turning the last link by {math.degrees(want):+.2f} "
                            f"deg (nominal model) changed the inclinometer's tilt by "
                            f"{math.degrees(got):+.2f} deg, the opposite sign: check "
                            "inclinometer.axes.tilt (sign, raw axis)")
        elif not RATIO[0] * abs(want) - SLACK_RAD <= abs(got) <= RATIO[1] * abs(want) + SLACK_RAD:
            problems.append(f"a test move turning the last link by {math.degrees(want):+.2f} "
                            f"deg (nominal model) changed the inclinometer's tilt by "
                            f"{math.degrees(got):+.2f} deg: check inclinometer.axes.tilt "
                            "(raw axis, sign)")
    if problems:
        raise ConfigError("; ".join(problems) + " (nothing was recorded)", source=cfg.source)
    if distance:
        said.append(check_directions(session, q0))
    return "plausible at the reference: a test move read " + ", ".join(said)


def check_serial_reference(session, distance: bool, tilt: bool) -> str:
    """A robot file's arm at its reference: the draw-wire zeroed reads about zero, a
    test move of the fastest joint changes it by about the distance moved, the
    joints' directions (:func:`station.session.joint_directions.check_directions`) and,
    with the tool inclinometer
    (sm-distance-tilt), a turn of the joint that tilts the tool most changes roll and
    pitch each the way the nominal model says (a flipped axis sign, swapped axes),
    and the readings are within the sensor's range (``range_rad``)."""
    from calibration import simulate

    rig, robot, cfg, xi = session.rig, session.robot, session.config, session.nominal
    q0 = np.array(rig.qm(), dtype=float)
    if distance:
        rig.zero_drawwire()
    r0 = read_at_rest(rig)
    problems, said = [], []
    if distance and abs(r0["distance"]) > ZERO_TOL_M:
        problems.append(f"the draw-wire reads {r0['distance']:.6g} m right after it was zeroed "
                        f"at the reference (expected about 0): check drawwire.offset_m "
                        f"({cfg.drawwire.offset_m:g}) and drawwire.word_order "
                        f"({cfg.drawwire.word_order})")
    if tilt:
        problems += range_problems(cfg, {k: r0.get(k) for k in ("roll", "pitch")},
                                   "at the reference")
    if problems:
        raise ConfigError("; ".join(problems) + " (nothing was recorded)", source=cfg.source)
    if distance:
        J = position_jacobian(robot, xi, q0)
        speed = np.linalg.norm(J, axis=1)
        i = int(np.argmax(speed))
        dq = np.zeros(robot.n_actuators)
        dq[i] = MOVE_M / speed[i]
        want = float(np.linalg.norm(robot.fk(np.atleast_2d(q0 + dq), xi)[0, :3]
                                    - robot.fk(np.atleast_2d(q0), xi)[0, :3]))
        rig.move_to(q0 + dq)
        try:
            got = read_at_rest(rig)["distance"] - r0["distance"]
        finally:
            rig.move_to(q0)
        said.append(f"draw-wire {got * 100:.2f} cm for {want * 100:.2f} cm")
        if not RATIO[0] * want - SLACK_M <= got <= RATIO[1] * want + SLACK_M:
            raise ConfigError(f"a test move of {want * 100:.1f} cm (nominal model) changed the "
                              f"draw-wire's reading by {got:.6g} m: check drawwire.word_order "
                              f"({cfg.drawwire.word_order}) and drawwire.metres_per_count "
                              f"({cfg.drawwire.metres_per_count:g}) (nothing was recorded)",
                              source=cfg.source)
    if tilt:
        mount = tuple(session.extra.get(k, 0.0) for k in ("mount_x", "mount_y"))

        def reading(q):
            return simulate.measure("sm-distance-tilt", robot, xi, np.atleast_2d(q),
                                    reference_qm=q0, mount=mount)["tilt"][0]

        base = reading(q0)
        h = 1e-3
        T = np.array([(reading(q0 + h * np.eye(robot.n_actuators)[k]) - base) / h
                      for k in range(robot.n_actuators)])        # (n, 2) d(roll, pitch)/dqk
        k = int(np.argmax(np.linalg.norm(T, axis=1)))
        dq = np.zeros(robot.n_actuators)
        dq[k] = TURN_RAD / np.linalg.norm(T[k])
        want = _wrap(reading(q0 + dq) - base)
        rig.move_to(q0 + dq)
        try:
            r1 = read_at_rest(rig)
        finally:
            rig.move_to(q0)
        for a, axis in enumerate(("roll", "pitch")):
            got = _wrap(r1[axis] - r0[axis])
            said.append(f"{axis} {math.degrees(got):+.2f} deg for {math.degrees(want[a]):+.2f} "
                        "deg")
            if abs(want[a]) < TURN_RAD / 4:
                continue          # this move barely turns this axis: its sign is not seen
            problems += _tilt_problem(f"of qm{k + 1} turning the tool's", axis, want[a], got)
        if problems:
            raise ConfigError("; ".join(problems) + " (nothing was recorded)",
                              source=cfg.source)
    if distance:
        said.append(check_directions(session, q0))
    return "plausible at the reference: a test move read " + ", ".join(said)


def _wrap(a):
    return (np.asarray(a, dtype=float) + math.pi) % (2 * math.pi) - math.pi


def sensor_ranges(config) -> dict[str, float]:
    """Inclinometer channel -> its measuring range (rad, |reading| at most), where the
    station config gives one (``[inclinometer.axes] CH = {..., range_rad = R}``)."""
    incl = getattr(config, "inclinometer", None)
    if incl is None:
        return {}
    return {ch: a.range_rad for ch, a in incl.axes.items()
            if getattr(a, "range_rad", None) is not None}


def range_problems(config, readings: dict, where: str) -> list[str]:
    """The inclinometer channels of ``readings`` beyond their range, in words."""
    out = []
    for ch, r in sensor_ranges(config).items():
        v = readings.get(ch)
        if v is not None and abs(v) > r:
            out.append(f"the inclinometer's {ch} reads {math.degrees(v):+.1f} deg {where}, "
                       f"beyond its range of +-{math.degrees(r):.0f} deg "
                       f"(inclinometer.axes.{ch}.range_rad): mount it so that it reads about "
                       "0 there")
    return out


def _wrist_tilt(robot, xi, qm, guess) -> np.ndarray:
    from calibration.robots.agebot_pm import gravity_tilt, rot_xyz

    X = robot.fk(np.atleast_2d(qm), xi, guess=guess)
    roll, pitch = gravity_tilt(rot_xyz(X), (0.0, 0.0))
    return np.column_stack([roll, pitch])


def check_wrist(session) -> str | None:
    """At the wrist's start pose, before planning: a test move of TURN_RAD in roll and
    -2/3 of it in pitch (nominal model; unequal, so swapped axes show), read, move back. Raises ConfigError naming the
    inclinometer axis to check; returns the findings in words."""
    rig, robot, cfg = session.rig, session.robot, session.config
    if robot.name != "agebot-pm" or rig.inclinometer is None or not rig.can_move:
        return None
    from calibration.pm_start import feasible_start

    q0 = np.array(rig.qm(), dtype=float)
    X_now = session.kind.orientation_now()
    try:
        # the nominal corrected to reach this pose, as the scout round's planning model
        xi = feasible_start(robot, np.atleast_2d(q0), np.atleast_2d(X_now),
                            np.asarray(session.nominal, dtype=float))
        base = _wrist_tilt(robot, xi, q0, X_now)[0]
        h = 1e-2
        steps = q0 + h * np.eye(robot.n_actuators)
        J = (_wrist_tilt(robot, xi, steps, X_now) - base).T / h   # d(roll, pitch)/dq
        dq = np.linalg.lstsq(J, np.array([TURN_RAD, -TURN_RAD * 2 / 3]), rcond=None)[0]
        want = _wrist_tilt(robot, xi, q0 + dq, X_now)[0] - base
    except CalibrationError as e:
        # a wrist far from the nominal: the nominal cannot predict a test move here, which
        # says nothing of the sensor. The scout round's fit still refuses readings its
        # model cannot explain (station/planning/wrist_plan.py), before driving any further.
        return (f"no test move at the wrist's start: the nominal model cannot predict one "
                f"there ({e}); the scout round's fit checks the inclinometer's axes instead")
    r0 = read_at_rest(rig)
    rig.move_to(q0 + dq)
    try:
        r1 = read_at_rest(rig)
    finally:
        rig.move_to(q0)
    back = read_at_rest(rig)             # settled: the next reading is of the start pose at rest
    if np.max(np.abs(np.array([back["roll"], back["pitch"]]) - [r0["roll"], r0["pitch"]])) \
            > SLACK_RAD:
        raise ConfigError(f"the inclinometer did not read the start pose again after the test "
                          f"move (roll {math.degrees(r0['roll']):+.2f} -> "
                          f"{math.degrees(back['roll']):+.2f} deg, pitch "
                          f"{math.degrees(r0['pitch']):+.2f} -> {math.degrees(back['pitch']):+.2f}"
                          " deg): check the sensor's mounting and [inclinometer]",
                          source=cfg.source)
    problems, said = [], []
    for k, axis in enumerate(("roll", "pitch")):
        got = r1[axis] - r0[axis]
        said.append(f"{axis} {math.degrees(got):+.2f} deg for {math.degrees(want[k]):+.2f} deg")
        problems += _tilt_problem("turning the platform's", axis, want[k], got)
    if problems:
        raise ConfigError("; ".join(problems) + " (nothing was recorded)", source=cfg.source)
    return "plausible at the wrist's start: a test move read " + ", ".join(said)


def _tilt_problem(move: str, axis: str, want: float, got: float) -> list[str]:
    """What is wrong (nothing, or one sentence) where a test move ``move`` (e.g. "turning
    the platform's") should turn the inclinometer's ``axis`` by ``want`` and turned it by
    ``got`` (rad): the opposite sign, or far from the nominal model's ratio."""
    said = (f"a test move {move} {axis} by {math.degrees(want):+.2f} deg (nominal model) "
            f"changed the inclinometer's {axis} by {math.degrees(got):+.2f} deg")
    if got * want < 0 and abs(got) > SLACK_RAD:
        return [f"{said}, the opposite sign: check inclinometer.axes.{axis} (sign, raw axis)"]
    if not (WRIST_RATIO[0] * abs(want) - SLACK_RAD <= abs(got)
            <= WRIST_RATIO[1] * abs(want) + SLACK_RAD):
        return [f"{said}: check inclinometer.axes.{axis} (raw axis, sign)"]
    return []
