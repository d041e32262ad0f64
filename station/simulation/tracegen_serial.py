"""Simulated traces of a robot file (``trace generate --robot FILE``).

The poses are actuator values drawn uniformly in the middle 80 % of each
joint's limits; the readings come from the true robot there, plus noise.
Physical constraints are where the true robot really is: a group of
sm-self-redundancy poses shares the true tool position, sm-plane contacts lie
on the true plane. The header carries the robot file (``robot_file``), so the
trace is complete on its own (docs/robot-files.md, "Traces of a robot file").
"""
from __future__ import annotations

import numpy as np

from calibration.errors import CalibrationError, UnreachablePose
from calibration.identifiability import minimum_poses
from calibration.methods import METHODS, check_kind, extra_params
from calibration.methods.sm_plane import PLANE
from calibration.robots import get_robot
from station.planning.pose_design import readings
from station.recording.trace_writer import write_trace
from station.simulation.tracegen import attempts, pose_records

# rows per pose of each method on a robot file (eq. 60's p)
ROWS = {"sm-full-pose": 6, "sm-position": 3, "sm-distance": 1, "sm-distance-tilt": 3,
        "sm-plane": 1, "sm-self-redundancy": 3}
MIN_COS_PITCH = 0.2  # sm-full-pose: poses farther than ~78 deg from the rpy singularity
NOISE = ("position", "pose", "distance", "tilt")


def default_count(robot, method: str) -> int:
    """Eq. 60 over the robot file's free parameters and the method's extra ones."""
    free = robot.n_params - len(robot.fixed) + len(extra_params(method, robot))
    return minimum_poses(free, ROWS[method])


def _draw(robot, rng, n) -> np.ndarray:
    lo, hi = robot.limits[:, 0], robot.limits[:, 1]
    mid, half = (lo + hi) / 2, 0.4 * (hi - lo)
    return rng.uniform(mid - half, mid + half, size=(n, robot.n_actuators))


def _noise(noise: dict, ch: str, shape, rng) -> np.ndarray:
    s = np.asarray(noise.get(ch, 0.0), dtype=float)
    return rng.normal(size=shape) * s if np.any(s) else np.zeros(shape)


def generate(robot, method: str, truth_xi, *, nominal=None, noise=None, seed=0, count=None,
             mount=(0.0, 0.0), plane=None, known=()):
    """Plan and simulate a data set of a robot file's ``robot`` (a SerialRobot).
    Returns ``(header, reference, poses)``; see :func:`station.simulation.tracegen.generate`."""
    check_kind(method, robot)
    if method not in ROWS:
        raise CalibrationError(f"method {method} cannot be simulated on a robot file")
    xi = np.asarray(truth_xi, dtype=float)
    nom = robot.nominal.copy() if nominal is None else np.asarray(nominal, dtype=float)
    rng = np.random.default_rng(seed)
    noise = {k: v for k, v in (noise or {}).items() if k in NOISE}
    count = count or default_count(robot, method)
    mi = METHODS[method]
    header = {"robot": robot.name, "robot_file": dict(robot.spec.source), "method": method,
              "nominal": robot.as_dict(nom),
              "station": {"generator": "station.simulation.tracegen_serial", "seed": seed}}
    sig = {k: (list(v) if isinstance(v, (list, tuple)) else v) for k, v in noise.items()
           if k in mi.channels}
    if sig:
        header["sigma"] = sig
    reference, group, channels = None, None, {}
    if method in ("sm-distance", "sm-distance-tilt"):
        qref = robot.limits.mean(axis=1)
        reference = {"role": mi.reference, "qm": qref.tolist()}
    if method == "sm-self-redundancy":
        qm, group = _groups(robot, xi, count, rng)
    elif method == "sm-plane":
        plane, qm = _contacts(robot, xi, plane, count, rng)
        for k in known:
            if k in PLANE:
                header["nominal"][k] = float(plane[PLANE.index(k)])
    else:
        qm = _draw(robot, rng, count)
        if method == "sm-full-pose":
            while True:
                bad = np.abs(np.cos(robot.fk(qm, xi)[:, 4])) < MIN_COS_PITCH
                if not bad.any():
                    break
                qm[bad] = _draw(robot, rng, int(bad.sum()))
    m = len(qm)
    channels = readings(robot, method, xi, qm, reference_qm=None if reference is None else qref,
                        mount=mount)
    for ch, shape in (("position", (m, 3)), ("pose", (m, 6)), ("distance", m), ("tilt", (m, 2))):
        if ch in channels:
            channels[ch] = channels[ch] + _noise(noise, ch, shape, rng)
    if "pose" in channels:
        channels["pose"][:, 3:] = (channels["pose"][:, 3:] + np.pi) % (2 * np.pi) - np.pi
    if method == "sm-distance-tilt":
        header["nominal"].update(mount_x=0.0, mount_y=0.0)
    for name in known:
        if name not in PLANE:
            header["nominal"][name] = float(xi[robot.index(name)])
    return header, reference, pose_records(qm, channels, group)


def _groups(robot, xi, count, rng, spread: float = 0.1):
    """sm-self-redundancy: ``count`` pairs of poses at one true tool position; the
    second pose starts up to ``spread`` of each joint's range away and moves back to it."""
    qm, group = [], []
    for _ in attempts(count, "cannot find enough pose pairs within the limits"):
        if len(group) >= 2 * count:
            break
        q1 = _draw(robot, rng, 1)[0]
        start = q1 + rng.uniform(-spread, spread, size=q1.size) * np.ptp(robot.limits, axis=1)
        try:
            q2 = robot.move_to(start, robot.frames(q1, xi)[0, :3, 3], xi)
        except UnreachablePose:
            continue
        g = len(group) // 2
        qm += [q1, q2]
        group += [g, g]
    return np.array(qm), np.array(group)


def _contacts(robot, xi, plane, count, rng):
    """sm-plane: poses of the true robot on a plane (default: through the middle of
    the drawn workspace, normal (1, 0.3, 0.2))."""
    if plane is None:
        c = robot.fk(_draw(robot, rng, 50), xi)[:, :3].mean(axis=0)
        n = np.array([1.0, 0.3, 0.2]) / np.linalg.norm([1.0, 0.3, 0.2])
        plane = -n / float(n @ c)
    a = np.asarray(plane, dtype=float)
    qm = []
    for _ in attempts(count, "the plane crosses too little of the reachable workspace"):
        if len(qm) >= count:
            break
        q = _draw(robot, rng, 1)[0]
        p = robot.frames(q, xi)[0, :3, 3]
        p = p - (a @ p + 1.0) * a / (a @ a)
        try:
            qm.append(robot.move_to(q, p, xi))
        except UnreachablePose:
            continue
    return a, np.array(qm)


def generate_trace(path, robot, method: str, truth_xi, **kw) -> None:
    header, reference, poses = generate(robot, method, truth_xi, **kw)
    write_trace(path, header, reference, poses)


def generate_command(args) -> str:
    """``app.py trace generate --robot FILE``: the truth is ``--truth`` (a truth file
    of this robot file) or the file's nominal; ``--noise CHANNEL=STD`` adds to the
    truth file's noise. Writes ``args.out`` atomically; returns a summary line."""
    from drivers.robot_file import load_robot_file
    from drivers.sim.truth import load_truth

    spec = load_robot_file(args.robot)
    robot = get_robot(spec)
    mount, plane, noise = (0.0, 0.0), None, {}
    xi = robot.nominal.copy()
    if args.truth:
        truth = load_truth(args.truth)
        if truth.spec is None or truth.spec.source["sha256"] != spec.source["sha256"]:
            raise CalibrationError(f"{args.truth}: the truth is not of the robot file {args.robot}")
        xi, mount, plane, noise = truth.xi(), truth.inclinometer_mount, truth.plane, dict(truth.noise)
    from station.simulation.tracegen import parse_noise

    for item in args.noise or ():
        k, v = next(iter(parse_noise([item], args.method).items()))
        if k not in NOISE:
            raise CalibrationError(f"--noise {item}: unknown channel {k!r} for a robot file "
                                   f"(known: {', '.join(NOISE)})")
        noise[k] = v
    known = tuple(k for k in (args.known or "").split(",") if k)
    header, reference, poses = generate(robot, args.method, xi, noise=noise, seed=args.seed,
                                        count=args.count, mount=mount, plane=plane, known=known)
    write_trace(args.out, header, reference, poses)
    return f"trace written to {args.out} ({len(poses)} poses of {robot.name}, {args.method})"
