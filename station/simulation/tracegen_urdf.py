"""Simulated measurements of a URDF robot by points on its tool (``sm-markers``), as a
laser tracker or a motion capture and the robot's controller would export them
(tests, ``app.py trace generate --robot FILE.urdf``).

A drawn robot (:func:`draw_truth`: joint origins off by millimetres and milliradians,
joint zeros by milliradians), an instrument placed anywhere (:func:`draw_frame`),
points fixed on the tool at unknown places (:func:`draw_points`), poses drawn inside
the joint limits; the readings are the truth's prediction plus isotropic noise.
:func:`write_csv` writes them the way the instrument and the controller print them:
the instrument's own frame, millimetres or metres, joint values in degrees through
a controller's joint map (signs, zeros, a J2/J3 coupling).
"""
from __future__ import annotations

import csv
import io
import math

import numpy as np

from calibration.robots.serial import rpy_of

# A drawn robot's spread (1 sigma): joint origins, joint zeros.
ORIGIN_SHIFT = 1e-3      # m
ORIGIN_TURN = 1e-3       # rad
ZERO = 5e-3              # rad (m for a prismatic joint: ZERO / 10)


def draw_truth(robot, rng, *, shift=ORIGIN_SHIFT, turn=ORIGIN_TURN, zero=ZERO) -> np.ndarray:
    """The robot's parameters around its URDF values (the base frame left at 0)."""
    x = robot.nominal.copy()
    for i, jt in enumerate(robot.spec.joints, start=1):
        x[robot.index(f"q{i}_off")] = rng.normal(0, zero if jt.kind == "R" else zero / 10)
        for k in ("x", "y", "z"):
            x[robot.index(f"j{i}_{k}")] = rng.normal(0, shift)
        for k in ("rx", "ry", "rz"):
            x[robot.index(f"j{i}_{k}")] = rng.normal(0, turn)
    return x


def draw_compliance(robot, x, rng, *, deflection: float = 2e-3) -> np.ndarray:
    """``x`` with each joint's compliance drawn so that its largest gravity load over
    the joint limits bends it by about ``deflection`` (rad; a prismatic joint m) times
    0.5-1.5; a joint that carries no load keeps 0. The robot must be compliant."""
    x = np.array(x, dtype=float)
    qm = draw_poses(robot, 200, np.random.default_rng(0), margin=0.0)
    tau = np.abs(robot.loads(qm)).max(axis=0)
    for i, t in enumerate(tau, start=1):
        if t > 1e-6:
            x[robot.index(f"c{i}")] = deflection / t * rng.uniform(0.5, 1.5)
    return x


def draw_frame(rng, *, vertical_tilt_deg: float | None = None, distance: float = 2.5):
    """The robot's base link in the instrument's frame: ``(R (3, 3), t (3,))``. Any
    orientation, or (``vertical_tilt_deg``) the instrument's z within that angle of
    the base's z (a level tracker, a mocap room with z up), turned about z at random."""
    if vertical_tilt_deg is None:
        q = rng.normal(size=4)
        q /= np.linalg.norm(q)
        w, x, y, z = q
        R = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                      [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                      [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])
    else:
        yaw = rng.uniform(-math.pi, math.pi)
        tilt = math.radians(vertical_tilt_deg)
        d = rng.uniform(-math.pi, math.pi)
        ax = np.array([math.cos(d), math.sin(d), 0.0])
        K = np.array([[0, -ax[2], ax[1]], [ax[2], 0, -ax[0]], [-ax[1], ax[0], 0]])
        Rt = np.eye(3) + math.sin(tilt) * K + (1 - math.cos(tilt)) * K @ K
        c, s = math.cos(yaw), math.sin(yaw)
        R = Rt @ np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    direction = rng.normal(size=3)
    t = distance * direction / np.linalg.norm(direction)
    return R, t


def frame_parameters(robot, x, R, t) -> np.ndarray:
    """``x`` with the base frame set to ``(R, t)`` (held rpy, no correction)."""
    x = np.array(x, dtype=float)
    roll, pitch, yaw = rpy_of(np.asarray(R)[None])[0]
    for name, v in (("base_x", t[0]), ("base_y", t[1]), ("base_z", t[2]), ("base_roll", roll),
                    ("base_pitch", pitch), ("base_yaw", yaw), ("base_rx", 0.0),
                    ("base_ry", 0.0), ("base_rz", 0.0)):
        x[robot.index(name)] = v
    return x


def draw_points(rng, count: int, *, reach: float = 0.12) -> np.ndarray:
    """``(count, 3)`` points on the tool (tip link frame), 3-15 cm from its origin."""
    out = []
    while len(out) < count:
        p = rng.uniform(-reach, reach, size=3)
        if 0.03 < np.linalg.norm(p) < reach * 1.3:
            out.append(p)
    return np.array(out)


def draw_poses(robot, count: int, rng, *, margin: float = 0.1) -> np.ndarray:
    """``(count, n)`` joint values drawn inside the limits (``margin`` of each range kept
    free at both ends)."""
    lo, hi = robot.limits[:, 0], robot.limits[:, 1]
    span = hi - lo
    return rng.uniform(lo + margin * span, hi - margin * span, size=(count, len(lo)))


def readings(robot, x, points, qm, rng, noise: float, *, unseen: float = 0.0) -> np.ndarray:
    """``(m, M, 3)`` the points in the instrument's frame with isotropic noise; each
    point missed with probability ``unseen`` (NaN; every pose keeps one)."""
    T = robot.frames(qm, x)
    P = T[:, None, :3, 3] + np.einsum("mij,kj->mki", T[:, :3, :3], points)
    P = P + rng.normal(0.0, noise, size=P.shape)
    if unseen > 0:
        miss = rng.uniform(size=P.shape[:2]) < unseen
        miss[np.arange(len(P)), rng.integers(0, P.shape[1], size=len(P))] = False
        P[miss] = np.nan
    return P


def write_csv(columns: dict, points: np.ndarray, *, length_scale: float = 1.0,
              use: list | None = None, style: str = "m") -> str:
    """CSV text: ``columns`` (name -> ``(m,)`` values, as printed), the points in
    ``1/length_scale`` units (``style`` ``"m"``: ``m1_x``; ``"xyz"``: ``x1``), empty
    cells for points not seen, and a ``use`` column if given."""
    out = io.StringIO()
    w = csv.writer(out, lineterminator="\n")
    M = points.shape[1]
    pcols = [(f"m{j}_{a}" if style == "m" else f"{a}{j}") for j in range(1, M + 1) for a in "xyz"]
    head = list(columns) + pcols + (["use"] if use is not None else [])
    w.writerow(head)
    for i in range(points.shape[0]):
        row = [repr(float(columns[c][i])) for c in columns]
        for j in range(M):
            p = points[i, j]
            row += ([""] * 3 if not np.all(np.isfinite(p))
                    else [repr(float(v / length_scale)) for v in p])
        if use is not None:
            row.append(use[i])
        w.writerow(row)
    return out.getvalue()


def load_urdf_truth(path, robot):
    """A truth file of a URDF robot: ``{"robot_file": PATH, "base_link", "tip_link",
    "parameters": {name: value}, "points": [[x, y, z], ...], "noise": {"marker": std}}``
    (names left out take the URDF's values; the frame's ``base_*`` too). Returns
    ``(x, points (M, 3), noise)``."""
    import json

    from calibration.errors import ConfigError

    try:
        doc = json.loads(open(path, encoding="utf-8").read())
    except (OSError, ValueError) as e:
        raise ConfigError(f"cannot read the truth file: {e}", source=str(path)) from None
    if not isinstance(doc, dict):
        raise ConfigError("a truth file is a JSON object", source=str(path))
    x = robot.params(doc.get("parameters") or {}, source=str(path))
    pts = np.asarray(doc.get("points") or [], dtype=float).reshape(-1, 3) if doc.get("points") \
        else None
    noise = float((doc.get("noise") or {}).get("marker", 0.0))
    if not (math.isfinite(noise) and noise >= 0):
        raise ConfigError("noise.marker must be a non-negative number of metres",
                          source=str(path))
    return x, pts, noise


def generate_command(args) -> str:
    """``app.py trace generate --robot FILE.urdf --base-link B --tip-link T --method
    sm-markers``: a drawn robot (or ``--truth``), the instrument placed at random, points
    on the tool, poses inside the limits, isotropic noise (``--noise marker=STD``); the
    trace's start values are what ``trace import`` would estimate."""
    from calibration.errors import ConfigError
    from calibration.robots import get_robot
    from drivers.urdf_file import load_urdf
    from station.recording.import_markers import start_values
    from station.recording.trace_writer import write_trace

    if args.method != "sm-markers":
        raise ConfigError(f"a URDF robot is simulated with sm-markers (points on the tool), "
                          f"not {args.method}")
    robot = get_robot(load_urdf(args.robot, args.base_link, args.tip_link))
    rng = np.random.default_rng(args.seed)
    count = args.count or 6 * robot.n_actuators + 10
    noise = 0.0
    if args.truth:
        x, u, noise = load_urdf_truth(args.truth, robot)
        if u is None:
            u = draw_points(rng, 3)
        drawn = f"the truth of {args.truth}"
    else:
        x = draw_truth(robot, rng)
        R, t = draw_frame(rng)
        x = frame_parameters(robot, x, R, t)
        u = draw_points(rng, 3)
        drawn = f"a robot drawn around the URDF (seed {args.seed})"
    for item in args.noise or ():
        k, _, v = item.partition("=")
        try:
            noise = float(v)
        except ValueError:
            raise ConfigError(f"--noise {item}: {v!r} is not a number") from None
        if k != "marker" or not (math.isfinite(noise) and noise >= 0):
            raise ConfigError(f"--noise {item}: give marker=STD (m, >= 0)")
    qm = draw_poses(robot, count, rng)
    P = readings(robot, x, u, qm, rng, noise)
    header = {"robot": robot.name, "robot_file": dict(robot.spec.source), "method": "sm-markers",
              "markers": int(len(u)), "nominal": start_values(robot, qm, P, args.out),
              "station": {"generated": {"truth": drawn, "noise": {"marker": noise}},
                          "joints": list(robot.spec.joint_names)}}
    if noise > 0:
        header["sigma"] = {"marker": noise}
    poses = [{"index": i, "qm": [float(v) for v in q],
              "markers": [[float(c) for c in p] for p in P[i]]} for i, q in enumerate(qm)]
    write_trace(args.out, header, None, poses)
    return (f"trace written to {args.out} ({count} poses of {robot.name}, sm-markers, "
            f"{len(u)} points; {drawn})")


FANUC_MAP = """format = "calstation-joint-map"
version = 1
# the controller's J3 is counted from the horizontal: the URDF's joint_3 is J2 + J3
[[joint]]
urdf = "joint_3"
terms = { J2 = 1.0, J3 = 1.0 }
""" + "".join(f'[[joint]]\nurdf = "joint_{i}"\ncolumn = "J{i}"\n' for i in (1, 2, 4, 5, 6))


def tracker_export(folder, robot, seed: int, *, fit: int = 60, held: int = 20,
                   noise: float = 3e-5, points: int = 3, unseen: float = 0.05, tilt=0.6,
                   readings_override=None, edit=None):
    """A 6-axis arm with a FANUC controller (``joint_1 .. joint_6``) measured by a laser
    tracker, exported as a user gets it: ``folder/meas.csv`` (the tracker's raw frame in
    mm, three reflectors, beams broken at random, joint values in degrees with J3 from
    the horizontal, ``use`` fit/validation) and ``folder/map.toml`` (the joint map).
    Returns ``(truth x with the points, joint values (m, 6) rad, readings (m, M, 3) m)``.
    ``edit(qm)`` changes the drawn poses first; ``readings_override`` replaces the
    simulated readings (same poses). A compliant ``robot`` bends under gravity
    (:func:`draw_compliance`)."""
    from pathlib import Path

    folder = Path(folder)
    rng = np.random.default_rng(seed)
    x = draw_truth(robot, rng)
    if robot.spec.compliance:
        x = draw_compliance(robot, x, rng)
    R, t = draw_frame(rng, vertical_tilt_deg=tilt)
    x = frame_parameters(robot, x, R, t)
    u = draw_points(rng, points)
    qm = draw_poses(robot, fit + held, rng)
    if edit is not None:
        edit(qm)
    P = (readings(robot, x, u, qm, rng, noise, unseen=unseen) if readings_override is None
         else readings_override)
    deg = np.degrees(qm)
    cols = {"J1": deg[:, 0], "J2": deg[:, 1], "J3": deg[:, 2] - deg[:, 1], "J4": deg[:, 3],
            "J5": deg[:, 4], "J6": deg[:, 5]}
    (folder / "meas.csv").write_text(write_csv(cols, P, length_scale=1e-3,
                                               use=["fit"] * fit + ["validation"] * held))
    (folder / "map.toml").write_text(FANUC_MAP)
    return np.r_[x, u.reshape(-1)], qm, P


def equivalent_truth(trace, x_true):
    """The truth in a fit's terms: the fit of noise-free readings of the trace's fit
    poses (points unseen where the trace's are), from the trace's own start values:
    what the calibrated parameters must take for the truth. Its residual is zero."""
    from calibration.methods import MethodData, build
    from calibration.solver import SolverOptions, solve

    rob = trace.robot_model()
    data = trace.method_data()
    n = rob.n_params
    T = rob.frames(data.qm, x_true[:n])
    P = T[:, None, :3, 3] + np.einsum("mij,kj->mki", T[:, :3, :3], x_true[n:].reshape(-1, 3))
    P[np.isnan(data.channels["markers"])] = np.nan
    model = build("sm-markers", rob, MethodData(qm=data.qm, channels={"markers": P}),
                  trace.nominal_vector(rob, trace.extra_params()))
    return solve(model, SolverOptions(fixed=rob.fixed)), model


def errors_against_truth(outcome, x_true):
    """``(z, d2)``: a calibration's errors against the truth's equivalent over its
    identifiable parameters, divided by their reported std, and ``e^T C^-1 e``."""
    eq, _ = equivalent_truth(outcome.trace, x_true)
    res = outcome.result
    idx = [j for j, s in enumerate(res.status) if s.identifiable]
    e = res.x[idx] - eq.x[idx]
    names = list(res.covariance_names)
    ci = [names.index(res.names[j]) for j in idx]
    C = np.asarray(res.covariance)[np.ix_(ci, ci)]
    return e / res.std[idx], float(e @ np.linalg.solve(C, e))
