"""The built-in robots' plans: the reference pose, and the IK-planned poses of the arm.

Pure planning (no devices): the session asks for the reference pose an operator
should capture, then for the poses to drive to, planned with the IK of the best
model it has, within the robot's joint limits, counted by eq. 60 and ordered to
keep actuator travel short. Each planned pose is ``fit`` or ``validation``
(held out: measured, never fitted, used to check the result).

sm-plane and sm-self-redundancy (report 7.4, 7.3) are measured by *guided
touching*: each planned pose is an approach pose from which the operator (a
``touch`` callback of the session) brings the tool tip into contact, with a
physical plane (a contact point on the plane as the engineer measured it
roughly, approached from 2 cm on the base's side) or with a fixed mark (a pair
of poses at one ``(x, y)`` with the last link at about -12 and +12 deg, sharing a
``group``). Their non-identifiable parameters that influence the model must be
known (:data:`MUST_KNOW`).

The PM wrist is planned in growing rounds (:mod:`station.planning.wrist_plan`): a scout
round near home, then boxes widened only as far as the start model fitted to
the poses recorded so far has earned.
"""
from __future__ import annotations

import numpy as np

from calibration import planning
from calibration.errors import CalibrationError, UnreachablePose
from calibration.methods import METHODS
from calibration.methods.sm_distance_tilt import reframe_nominal
from calibration.robots import BUILTIN, get_robot
from station.fitting.pose_count import minimum_count
from station.recording.planned_pose import PlannedPose
from station.planning.request import PlanRequest

# where the operator puts the end effector for the reference (report 7.2 and 7.5)
SM_REFERENCE_POINT = np.array([1.0, 1.0, 0.0, 0.2])   # relative to the base offset
SM_BASE_ORIGIN = np.array([0.5, 1.0, 0.8, 0.0])       # absolute, elbow -1
TOUCH_STANDOFF = 0.02         # m: sm-plane approach poses this far from the rough plane
PAIR_PHI_DEG = (8.0, 16.0)    # sm-self-redundancy: |phi| of a pair's two poses, degrees



#: share of an actuator's range kept clear where a suggested reference is brought
#: inside the config's limits
REFERENCE_MARGIN = 0.05


def inside_limits(qm, qm_range) -> np.ndarray:
    """``qm`` with each actuator beyond the config's limits (``qm_range``: ``(n, 2)`` or
    None) brought :data:`REFERENCE_MARGIN` of its range inside them. The nominal
    model's suggestion of a reference is a suggestion: on a robot whose gear ratio
    is 30 % off, the nominal's -212.9 for actuator 4 lay beyond a limit of -205, and
    the session refused to move there."""
    qm = np.array(qm, dtype=float)
    if qm_range is None:
        return qm
    lo, hi = np.asarray(qm_range, dtype=float).T
    span = hi - lo
    pad = REFERENCE_MARGIN * np.where(np.isfinite(span), span, 0.0)   # none on an open side
    out = (qm < lo) | (qm > hi)
    qm[out] = np.clip(qm[out], (lo + pad)[out], (hi - pad)[out])
    return qm


def reference_pose(method: str, nominal, qm_range=None) -> tuple[np.ndarray | None, str | None, str]:
    """``(qm, role, instructions)`` of the reference step; qm None where the method has
    none. ``qm_range`` (the config's actuator limits): an actuator the suggestion puts
    beyond them is brought inside (:func:`inside_limits`)."""
    robot = get_robot(BUILTIN[METHODS[method].kind])
    if method == "sm-distance-tilt":
        qm = inside_limits(robot.ik(SM_BASE_ORIGIN, nominal, elbow=-1), qm_range)
        return qm, "base-origin", (
            "Jog the end effector to where the base origin of the calibration should be "
            "(inside the working area, about 0.5 m out, 1 m along the rail, 0.8 m up), attach "
            "the draw-wire cable to it there and capture: the draw-wire is zeroed and the "
            "actuator values recorded. theta0, a0 and q1_off will refer to this point.")
    if method == "sm-distance":
        off = np.r_[robot.base_offset(nominal), 0.0]
        qm = inside_limits(robot.ik(SM_REFERENCE_POINT + off, nominal), qm_range)
        return qm, "reference-point", (
            "Jog the end effector to the reference point, attach the draw-wire cable there "
            "and capture: the draw-wire is zeroed and the actuator values recorded.")
    return None, None, ("The wrist needs no reference. Check that the inclinometer is "
                        "mounted flat on the platform with its x axis along the platform's x "
                        "axis: at the home pose it should read roll and pitch near 0.")


def plan_sm(method: str, nominal, reference_qm, req: PlanRequest, *,
            plane=None, box_scale: float = 1.0, accept=None, first_index: int = 0,
            rnd: int = 0, start_qm=None, box_centre=None,
            design_out: list | None = None, measured_qm=()) -> list[PlannedPose]:
    """The poses of an SM method (``reference_qm``: the reference; travel starts there or
    at ``start_qm``). sm-plane needs ``plane`` ``(a, b, c)``; sm-self-redundancy counts
    pairs (``req.count`` pairs to fit, ``req.validation`` pairs held out). The distance
    methods' box is shrunk by ``box_scale`` (about the base origin for sm-distance-tilt,
    about the box's middle for sm-distance), sm-distance-tilt's moved to ``box_centre``
    (the reference pose as read there), and ``accept(X, qm)`` filters the poses (the
    envelope's actuator limits); ``first_index``, ``rnd``: the poses' plan indices and
    round (:mod:`station.planning.arm_rounds`). With ``req.design == "optimal"`` the distance
    methods' fit poses are the D-optimal choice of ten times as many candidates
    (:func:`station.planning.pose_design.choose`) given the fit poses already measured
    (``measured_qm``, a session's earlier rounds); the design's record is appended to
    ``design_out``."""
    robot = get_robot("agebot-sm")
    rng = np.random.default_rng(req.seed)
    count = req.count or int(np.ceil(req.margin * minimum_count(method)))
    n_val = req.validation if req.validation is not None else max(3, count // 5)
    total = count + n_val
    from station.planning.pose_design import POOL_FACTOR, choose

    designed = req.design != "random" and method in ("sm-distance", "sm-distance-tilt")
    draw = POOL_FACTOR * total if designed else total
    if method == "sm-plane":
        return _plane_poses(robot, nominal, plane, count, n_val, rng, reference_qm, accept)
    if method == "sm-self-redundancy":
        return _pair_poses(robot, nominal, count, n_val, rng, reference_qm, accept)
    if method == "sm-distance-tilt":
        framed = reframe_nominal(robot, nominal, reference_qm)
        elbow = robot.elbow_of(reference_qm, nominal)
        box = planning.box_array(robot, planning.SM_BOX_7_5)
        centre = np.zeros(4) if box_centre is None else np.asarray(box_centre, dtype=float)
        bounds = planning.scale_box(box, box_scale, np.zeros(4)) + centre[:, None]
        plan = planning.sample_poses(robot, framed, bounds,
                                     draw, rng, ik_options={"elbow": elbow}, accept=accept)
    else:
        off = np.r_[robot.base_offset(nominal), 0.0]
        box = planning.box_array(robot, planning.SM_BOX_7_1, off)
        plan = planning.sample_poses(robot, nominal, planning.scale_box(box, box_scale, box_centre),
                                     draw,
                                     rng, accept=accept)
    start = reference_qm if start_qm is None else start_qm
    targets, qm, validation = plan.targets, plan.qm, None
    if designed:
        fit_idx, design = choose(method, robot, nominal, qm, count, measured=measured_qm,
                                 design=req.design, rng=rng,
                                 reference_qm=reference_qm, distance_zero="reading",
                                 target=req.target, heldout_qm=qm[:50])
        rest = np.setdiff1d(np.arange(len(qm)), fit_idx)
        keep = np.r_[fit_idx, rng.choice(rest, size=n_val, replace=False)].astype(int)
        targets, qm = targets[keep], qm[keep]
        validation = np.arange(len(fit_idx), len(keep))
        if design_out is not None:
            design_out.append(design.as_record())
    return _finish(robot, targets, qm, n_val, rng, start, first_index, rnd,
                   validation=validation)


#: the arm's scout step from the reference, per actuator, in joint units under the
#: start model (rail m, joints rad): small enough that gear ratios 40 % off move the
#: tip only a few cm away from where the start model puts it
SM_SCOUT_STEP = (0.1, 0.05, 0.05, 0.05)


def plan_sm_scout(xi, reference_qm, count: int, seed: int, *, accept=None,
                  first_index: int = 0, step=SM_SCOUT_STEP) -> list[PlannedPose]:
    """Round 0 of the arm's distance methods: ``count`` poses a small random actuator
    step from the reference (``step / |k|`` per axis under the model ``xi``), no IK:
    near the reference the start model's error is a fraction of a small motion, far
    from it the same error may be a crash. ``target`` is where ``xi`` puts them."""
    robot = get_robot("agebot-sm")
    rng = np.random.default_rng(seed)
    ref = np.asarray(reference_qm, dtype=float)
    k = np.abs([xi[robot.index(f"k{i + 1}")] for i in range(robot.n_actuators)])
    delta = np.asarray(step, dtype=float) / k
    qm = []
    for _ in range(400 * count):
        q = ref + rng.uniform(-1.0, 1.0, len(ref)) * delta
        if accept is None or accept(None, q):
            qm.append(q)
        if len(qm) == count:
            break
    if len(qm) < count:
        raise CalibrationError(f"only {len(qm)} of {count} scout poses near the reference are "
                               "inside the actuator limits: is the reference at a limit?")
    qm = np.array(qm)
    return _finish(robot, robot.fk(qm, xi), qm, 0, rng, ref, first_index, 0)


def _sm_box(robot, nominal) -> np.ndarray:
    return planning.box_array(robot, planning.SM_BOX_7_1, np.r_[robot.base_offset(nominal), 0.0])


def _plane_poses(robot, nominal, plane, count, n_val, rng, start_qm,
                 accept=None) -> list[PlannedPose]:
    """Contact points on the rough plane inside the 7.1 box (the plane's steepest
    coordinate solved for), each approached from ``TOUCH_STANDOFF`` on the base side."""
    if plane is None:
        raise CalibrationError("sm-plane needs the plane (plane_a, plane_b, plane_c) to plan")
    a = np.asarray(plane, dtype=float)
    if not np.all(np.isfinite(a)) or not np.any(a):
        raise CalibrationError(f"the plane {a.tolist()} is not a plane a x + b y + c z + 1 = 0")
    normal = a / np.linalg.norm(a)       # towards a x + b y + c z + 1 > 0: the base's side
    box = _sm_box(robot, nominal)
    k = int(np.argmax(np.abs(a)))
    rest = [i for i in range(3) if i != k]
    targets, qm = [], []
    draws, total = 0, count + n_val
    while len(qm) < total:
        draws += 1
        if draws > 400 * total:
            raise CalibrationError(f"only {len(qm)} of {total} contact points on the plane "
                                   f"{a.tolist()} are reachable inside the workspace box: is "
                                   "the plane measured in the robot's base frame?")
        X = rng.uniform(box[:, 0], box[:, 1])
        X[k] = -(1.0 + a[rest] @ X[rest]) / a[k]
        if not box[k, 0] <= X[k] <= box[k, 1]:
            continue
        approach = X.copy()
        approach[:3] += TOUCH_STANDOFF * normal
        try:
            q = robot.ik(approach, nominal, elbow=1)
        except UnreachablePose:
            continue
        if accept is not None and not accept(approach, q):
            continue
        targets.append(X)
        qm.append(q)
    return _finish(robot, np.array(targets), np.array(qm), n_val, rng, start_qm, 0, 0)


def _pair_poses(robot, nominal, count, n_val, rng, start_qm, accept=None) -> list[PlannedPose]:
    """``count + n_val`` pairs at one (x, y, z) each, phi in -16..-8 and 8..16 degrees
    (one elbow); pairs held out whole and visited whole, first pose first."""
    box = _sm_box(robot, nominal)
    lo, hi = np.radians(PAIR_PHI_DEG)
    pairs = []
    draws, total = 0, count + n_val
    while len(pairs) < total:
        draws += 1
        if draws > 400 * total:
            raise CalibrationError(f"only {len(pairs)} of {total} pose pairs are reachable "
                                   "inside the workspace box")
        X = rng.uniform(box[:, 0], box[:, 1])
        X1, X2 = X.copy(), X.copy()
        X1[3], X2[3] = -rng.uniform(lo, hi), rng.uniform(lo, hi)
        try:
            q1, q2 = robot.ik(X1, nominal, elbow=1), robot.ik(X2, nominal, elbow=1)
        except UnreachablePose:
            continue
        if accept is not None and not (accept(X1, q1) and accept(X2, q2)):
            continue
        pairs.append((X1, X2, q1, q2))
    use = np.array(["fit"] * total, dtype=object)
    if n_val:
        use[rng.choice(total, size=n_val, replace=False)] = "validation"
    order = planning.order_for_travel(np.array([p[2] for p in pairs]), start=start_qm)
    out = []
    for g, i in enumerate(order):
        X1, X2, q1, q2 = pairs[i]
        for X, q in ((X1, q1), (X2, q2)):
            out.append(PlannedPose(len(out), tuple(float(v) for v in q),
                                   tuple(float(v) for v in X), str(use[i]), 0, g))
    return out


def _finish(robot, targets, qm, n_val, rng, start_qm, first_index, rnd, *,
            validation=None) -> list[PlannedPose]:
    """Pick held-out poses at random (or those at the indices ``validation``) and order
    for short travel (the IK already refused poses outside the joint limits:
    ``AgebotSM.ik`` checks them)."""
    use = np.array(["fit"] * len(qm), dtype=object)
    if validation is not None:
        use[np.asarray(validation, dtype=int)] = "validation"
    elif n_val:
        use[rng.choice(len(qm), size=n_val, replace=False)] = "validation"
    order = planning.order_for_travel(qm, start=start_qm)
    return [PlannedPose(first_index + k, tuple(float(v) for v in qm[i]),
                        tuple(float(v) for v in targets[i]), str(use[i]), rnd)
            for k, i in enumerate(order)]
