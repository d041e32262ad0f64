"""Simulated traces from a truth file plus noise (fixtures, tests, demos).

The poses are planned as the station plans them (IK of the nominal model in the
report's workspace boxes, one elbow configuration); the readings come from the
true robot at the commanded actuator values. Physical constraints (the touched
points of sm-self-redundancy and sm-plane, the reference points) are where the
true robot really is.
"""
from __future__ import annotations

import math

import numpy as np

from calibration import planning, simulate
from calibration.errors import CalibrationError, ConfigError, UnreachablePose
from calibration.methods import METHODS
from calibration.methods.sm_distance_tilt import reframe_nominal
from calibration.robots import BUILTIN, get_robot
from station.planning import pose_design
from station.planning.arm_plan import SM_BASE_ORIGIN, SM_REFERENCE_POINT
from station.fitting.pose_count import minimum_count
from station.recording.trace_writer import write_trace

DEFAULT_PLANE_NORMAL = np.array([1.0, 0.3, 0.2])


def default_plane(xi_true, robot) -> np.ndarray:
    """A tilted plane through the middle of the report's 7.1 box."""
    n = DEFAULT_PLANE_NORMAL / np.linalg.norm(DEFAULT_PLANE_NORMAL)
    c = robot.base_offset(xi_true) + np.array([1.25, 0.75, 0.0])
    return -n / float(n @ c)


def generate(method: str, truth_xi, *, nominal=None, plane=None, noise=None, seed=0,
             count=None, components=None, mount=(0.0, 0.0), known=(), design="random"):
    """Plan and simulate a data set. Returns ``(header, reference, poses)`` records.

    design: ``"random"`` (poses drawn in the workspace box) or ``"optimal"`` (the
    D-optimal ``count`` of a pool of candidates drawn the same way,
    :mod:`station.planning.pose_design`; the header's ``station.design`` records the predicted
    accuracy).

    known: parameter names whose true values are written into the header's
    nominal (what the report assumes known for the methods whose
    non-identifiable parameters influence the model; plane_a/b/c for sm-plane)."""
    mi = METHODS[method]
    robot = get_robot(BUILTIN[mi.kind])
    xi_true = np.asarray(truth_xi, dtype=float)
    nom = robot.nominal.copy() if nominal is None else np.asarray(nominal, dtype=float)
    rng = np.random.default_rng(seed)
    noise = dict(noise or {})
    count = count or minimum_count(method, components, distance_zero="exact")   # its zero is exact
    if design not in pose_design.DESIGNS:
        raise CalibrationError(f"unknown design {design!r} (known: "
                               f"{', '.join(pose_design.DESIGNS)})")
    wanted = count
    if design == "optimal":
        count = pose_design.POOL_FACTOR * count
    reference = None
    group = None
    header = {"robot": robot.name, "method": method,
              "nominal": robot.as_dict(nom),
              "station": {"generator": "station.simulation.tracegen", "seed": seed}}
    meas_noise = {k: v for k, v in noise.items()
                  if k in ("pose", "position", "distance", "tilt", "orientation")}
    if meas_noise:
        header["sigma"] = {k: (list(v) if isinstance(v, (list, tuple)) else v)
                           for k, v in meas_noise.items() if k in mi.channels}
    if mi.kind == "serial":
        off = np.r_[robot.base_offset(nom), 0.0]
        box = planning.box_array(robot, planning.SM_BOX_7_1, off)
        if method in ("sm-full-pose", "sm-position"):
            plan = planning.sample_poses(robot, nom, box, count, rng)
            qm = plan.qm
        elif method == "sm-distance":
            qref = robot.ik(SM_REFERENCE_POINT + off, nom)
            reference = {"role": "reference-point", "qm": qref.tolist()}
            plan = planning.sample_poses(robot, nom, box, count, rng)
            qm = plan.qm
        elif method == "sm-distance-tilt":
            qb = robot.ik(SM_BASE_ORIGIN, nom, elbow=-1)
            reference = {"role": "base-origin", "qm": qb.tolist()}
            framed = reframe_nominal(robot, nom, qb)
            elbow = robot.elbow_of(qb, nom)
            plan = planning.sample_poses(robot, framed, planning.box_array(robot, planning.SM_BOX_7_5),
                                         count, rng, ik_options={"elbow": elbow})
            qm = plan.qm
        elif method == "sm-self-redundancy":
            qm, group = _pairs(robot, xi_true, box, count, rng)
        elif method == "sm-plane":
            plane = default_plane(xi_true, robot) if plane is None else np.asarray(plane, float)
            qm = _plane_contacts(robot, xi_true, plane, box, count, rng)
        else:  # pragma: no cover
            raise CalibrationError(f"{method} cannot be simulated on {robot.name}")
    else:
        # the report's nominal wrist cannot even reach X = 0 (its rods are too
        # short), so the orientations are those the true wrist is driven to
        bounds = planning.box_array(robot, planning.PM_BOX)
        plan = planning.sample_poses(robot, xi_true, bounds, count, rng)
        qm = plan.qm
        if method == "pm-fk" and components:
            header["components"] = list(components)
    if design == "optimal":
        x_plan = xi_true if mi.kind == "parallel-wrist" else nom
        ref_qm = None if reference is None else np.array(reference["qm"])
        model = pose_design.pool_model(method, robot, x_plan, qm, reference_qm=ref_qm,
                                       group=group, components=components, mount=mount,
                                       plane=plane)
        chosen = pose_design.design_poses(model, wanted, noise=pose_design.row_noise(method, noise),
                                          group=group)
        qm = qm[chosen.fit]
        if group is not None:
            group = np.unique(group[chosen.fit], return_inverse=True)[1]
        header["station"]["design"] = chosen.as_record()
    for name in known:
        if name in ("plane_a", "plane_b", "plane_c"):
            if method != "sm-plane":
                raise CalibrationError(f"{name} is a parameter of sm-plane only")
            header["nominal"][name] = float(plane[("plane_a", "plane_b", "plane_c").index(name)])
        else:
            header["nominal"][name] = float(xi_true[robot.index(name)])
    ref_qm = None if reference is None else np.array(reference["qm"])
    meas = simulate.measure(method, robot, xi_true, qm, reference_qm=ref_qm,
                            noise=meas_noise, rng=rng, mount=mount)
    if method == "pm-fk" and components and "orientation" in meas:
        meas["orientation"] = meas["orientation"][:, [("alpha", "beta", "gamma").index(c)
                                                      for c in components]]
    return header, reference, pose_records(qm, meas, group)


def pose_records(qm, channels: dict, group=None) -> list[dict]:
    """The trace's pose records: index, actuator values, the group where poses
    come in groups, and each channel's reading (a number or a list)."""
    poses = []
    for i in range(len(qm)):
        rec = {"index": i, "qm": [float(v) for v in qm[i]]}
        if group is not None:
            rec["group"] = int(group[i])
        for ch, arr in channels.items():
            v = arr[i]
            rec[ch] = v.tolist() if np.ndim(v) else float(v)
        poses.append(rec)
    return poses


def attempts(count: int, message: str):
    """Up to 400 tries per wanted pose, then :class:`CalibrationError` ``message``
    (``for _ in attempts(n, why):`` with a break once there are enough)."""
    for _ in range(400 * count):
        yield
    raise CalibrationError(message)


def _pairs(robot, xi_true, box, count, rng):
    """sm-self-redundancy: ``count`` pairs touching one (x, y) with phi about
    -12 and +12 degrees (the true robot really touches the same point)."""
    qm, group = [], []
    for _ in attempts(count, "cannot find enough reachable pose pairs"):
        if len(group) >= 2 * count:
            break
        X = rng.uniform(box[:, 0], box[:, 1])
        X1, X2 = X.copy(), X.copy()
        X1[3] = rng.uniform(math.radians(-20), math.radians(-5))
        X2[3] = rng.uniform(math.radians(5), math.radians(20))
        try:
            q1, q2 = robot.ik(X1, xi_true, elbow=1), robot.ik(X2, xi_true, elbow=1)
        except UnreachablePose:
            continue
        g = len(group) // 2
        qm += [q1, q2]
        group += [g, g]
    return np.array(qm), np.array(group)


def _plane_contacts(robot, xi_true, plane, box, count, rng):
    """sm-plane: points of the true robot on the plane inside the box."""
    a = np.asarray(plane, dtype=float)
    k = int(np.argmax(np.abs(a)))
    qm = []
    for _ in attempts(count, "the plane crosses too little of the reachable workspace"):
        if len(qm) >= count:
            break
        X = rng.uniform(box[:, 0], box[:, 1])
        rest = [i for i in range(3) if i != k]
        X[k] = -(1.0 + a[rest] @ X[rest]) / a[k]
        try:
            qm.append(robot.ik(X, xi_true, elbow=1))
        except UnreachablePose:
            continue
    return np.array(qm)


def generate_trace(path, method: str, truth_xi, **kw) -> None:
    """:func:`generate` and write the trace to ``path`` atomically."""
    header, reference, poses = generate(method, truth_xi, **kw)
    write_trace(path, header, reference, poses)


#: the noise channels of a method beyond its own (pm-tilt's two tilt axes by name)
NOISE_ALIASES = {"pm-tilt": ("roll", "pitch")}


def noise_channels(method: str) -> tuple[str, ...]:
    """The channels ``--noise`` takes for ``method`` (its readings)."""
    return tuple(METHODS[method].channels) + NOISE_ALIASES.get(method, ())


def parse_noise(items, method: str | None = None, flag: str = "--noise") -> dict:
    """``CHANNEL=STD`` strings (``app.py trace generate --noise``) as a dict;
    a malformed item, a std that is not a finite number > 0, or a name that is no
    channel of any method is a :class:`ConfigError` naming it (a channel ``method``
    does not read is ignored, as a truth file's noise of the other channels is)."""
    out = {}
    known = sorted({c for m in METHODS for c in noise_channels(m)})
    for item in items or ():
        k, eq, v = item.partition("=")
        k = k.strip()
        try:
            std = float(v)
        except ValueError:
            std = math.nan
        if not (eq and k and math.isfinite(std) and std >= 0):
            raise ConfigError(f"{flag} {item!r}: expected CHANNEL=STD with a number > 0, "
                              f"e.g. distance=1e-4")
        if std == 0:
            raise ConfigError(f"{flag} {item!r}: a std of 0 is no noise at all; leave {k} out "
                              "for noise-free readings")
        if k not in known:
            reads = (f"; {method} reads {', '.join(noise_channels(method)) or 'none'}"
                     if method in METHODS else "")
            raise ConfigError(f"{flag} {item!r}: unknown channel {k!r} (channels: "
                              f"{', '.join(known)}{reads})")
        out[k] = std
    return out


def reading_noise(method: str, noise: dict) -> dict:
    """The generator's noise for ``method`` from a truth file's and the command
    line's. pm-tilt's ``tilt`` has two axes: ``roll``/``pitch`` give them where
    ``tilt`` is not given, a single ``tilt`` value applies to both. (The SM's
    tilt is one angle: ``tilt`` only.)"""
    noise = dict(noise)
    if method == "pm-tilt":
        if "roll" in noise or "pitch" in noise:
            noise.setdefault("tilt", [noise.get("roll", 0.0), noise.get("pitch", 0.0)])
        if isinstance(noise.get("tilt"), float):
            noise["tilt"] = [noise["tilt"], noise["tilt"]]
    return noise


def generate_from_truth(path, method: str, *, truth: str | None = None, noise=(), seed=0,
                        count=None, components=None, known=(), design="random") -> dict:
    """``app.py trace generate``: a trace of ``method`` simulated on the robot of
    a truth file (``truth``: its path; None: the report's true values), with the
    truth file's noise overridden by ``noise`` (``CHANNEL=STD`` strings), written
    atomically to ``path``. Returns the reading noise used (empty: noise-free)."""
    mi = METHODS.get(method)
    if mi is None:
        raise ConfigError(f"unknown method {method!r} (known: {', '.join(METHODS)})")
    robot = get_robot(BUILTIN[mi.kind])
    plane, mount, base_noise = None, (0.0, 0.0), {}
    if truth:
        from drivers.sim.truth import load_truth

        t = load_truth(truth)
        if t.robot != robot.name:
            raise ConfigError(f"truth is for {t.robot}, method {method} needs {robot.name}",
                              source=str(truth))
        xi = t.xi()
        plane, mount, base_noise = t.plane, tuple(t.inclinometer_mount), dict(t.noise)
    else:
        xi = robot.true
    noise = reading_noise(method, {**base_noise, **parse_noise(noise, method)})
    generate_trace(path, method, np.asarray(xi), noise=noise, seed=seed, count=count,
                   components=components, plane=plane, mount=mount, known=tuple(known),
                   design=design)
    return noise


def candidate_pool(method: str, x_plan, size: int, *, seed=0, components=None, plane=None):
    """A pool of ``size`` candidate poses planned as :func:`generate` plans them on the
    robot ``x_plan`` (the current model), and the method's measurement model over it
    (:func:`station.planning.pose_design.pool_model`). Returns ``(model, qm, group)``."""
    mi = METHODS[method]
    robot = get_robot(BUILTIN[mi.kind])
    x_plan = np.asarray(x_plan, dtype=float)
    header, reference, poses = generate(method, x_plan, nominal=x_plan, plane=plane,
                                        seed=seed, count=size, components=components)
    qm = np.array([p["qm"] for p in poses], dtype=float)
    group = np.array([p["group"] for p in poses]) if poses and "group" in poses[0] else None
    ref = None if reference is None else np.array(reference["qm"], dtype=float)
    if method == "sm-plane" and plane is None:
        plane = default_plane(x_plan, robot)
    model = pose_design.pool_model(method, robot, x_plan, qm, reference_qm=ref, group=group,
                                   components=components, plane=plane)
    return model, qm, group
