"""Planning for any serial arm of a robot file (docs/robot-files.md, "Sessions").

Poses are drawn in joint space in the middle 80 % of each joint's limits (the
robot file's ``limits``, or the station config's ``[limits]`` where narrower) and
kept only where the current model puts the tool origin inside the workspace:
at least :data:`FLOOR_MARGIN` above the floor ``z = 0`` of the base frame and,
for the draw-wire methods, between :data:`WIRE_MIN` and :data:`WIRE_RANGE` from
the reference point. The reference point itself is a task-space target: the
middle of the safe candidates' tool positions, reached by the model's numerical
IK (:meth:`calibration.robots.serial.SerialRobot.move_to`) from the nearest
candidate. The poses to measure are chosen from the candidate pool by
D-optimality (:mod:`station.planning.pose_design`); their count is eq. 60 over the
parameters identifiable by the method on this robot (the QR analysis of the
pool), times the request's margin. The travel order keeps actuator motions
short (:func:`calibration.planning.order_for_travel`), and every motion, as the
drives make it (each axis at the same speed, so the shorter moves end first),
keeps the tool :data:`PATH_MARGIN` above the floor; a pose whose way there does
not is left out.
"""
from __future__ import annotations

import numpy as np

from calibration import planning
from calibration.errors import CalibrationError, UnreachablePose
from calibration.identifiability import minimum_poses
from station.planning import pose_design

FLOOR_MARGIN = 0.10   # m: planned tool origins this far above the floor z = 0
PATH_MARGIN = 0.03    # m: and every motion between them this far
WIRE_MIN, WIRE_RANGE = 0.10, 1.5   # m: draw-wire lengths the plan uses (cable range)
TILT_MARGIN = np.radians(5.0)   # rad: planned inclinometer readings this far inside its range
POOL = 600            # candidates drawn per plan
SPARE = (1.3, 2.0, 3.0)   # fit candidates per fit pose asked, tried in turn
ROWS = {"sm-distance": 1, "sm-distance-tilt": 3}   # rows per pose (eq. 60's p)
REFERENCE_TEXT = (
    "Jog the tool to the reference point (the planned pose is the middle of the safe "
    "workspace), attach the draw-wire cable to the tool there and capture: the draw-wire is "
    "zeroed and the actuator values recorded. Every distance is measured from this point.")


def joint_box(robot, qm_range=None) -> np.ndarray:
    """``(n, 2)`` actuator bounds: the middle 80 % of the limits, within ``qm_range``."""
    lim = np.array(robot.limits, dtype=float)
    if qm_range is not None:
        r = np.asarray(qm_range, dtype=float)
        lim = np.column_stack([np.maximum(lim[:, 0], r[:, 0]), np.minimum(lim[:, 1], r[:, 1])])
    mid, half = lim.mean(axis=1), 0.4 * (lim[:, 1] - lim[:, 0])
    return np.column_stack([mid - half, mid + half])


def readable(robot, xi, q, tilt_range) -> np.ndarray:
    """``(m,)`` bool: where the tool inclinometer (model ``xi``; ``tilt_range`` =
    ``(roll, pitch, mount)``: the sensor's ranges in rad, None where not stated, and its
    mounting) reads within its range less :data:`TILT_MARGIN` (the model's error)."""
    from calibration.robots.agebot_pm import gravity_tilt

    q = np.atleast_2d(q)
    if tilt_range is None:
        return np.ones(len(q), dtype=bool)
    r_roll, r_pitch, mount = tilt_range
    roll, pitch = gravity_tilt(robot.frames(q, xi)[:, :3, :3], mount)
    ok = np.ones(len(q), dtype=bool)
    for value, r in ((roll, r_roll), (pitch, r_pitch)):
        if r is not None:
            ok &= np.abs(value) <= max(r - TILT_MARGIN, 0.5 * r)
    return ok


def safe_pool(robot, xi, rng, count: int = POOL, qm_range=None, anchor=None,
              tilt_range=None) -> np.ndarray:
    """``count`` candidates at most: actuator values whose tool origin (model ``xi``) is
    above the floor with the margin and, with ``anchor``, within the draw-wire's range,
    and, with ``tilt_range`` (:func:`readable`), where the tool inclinometer reads."""
    box = joint_box(robot, qm_range)
    q = rng.uniform(box[:, 0], box[:, 1], size=(count, robot.n_actuators))
    p = robot.frames(q, xi)[:, :3, 3]
    ok = p[:, 2] >= FLOOR_MARGIN
    if anchor is not None:
        d = np.linalg.norm(p - anchor, axis=1)
        ok &= (d >= WIRE_MIN) & (d <= WIRE_RANGE)
    if not ok.any():
        raise CalibrationError(f"no pose of {robot.name} within its limits keeps the tool "
                               f"{FLOOR_MARGIN} m above the floor z = 0 of the base frame: is "
                               "the base frame's z axis up?")
    ok &= readable(robot, xi, q, tilt_range)
    if not ok.any():
        raise CalibrationError(
            f"no pose of {robot.name} within its limits has the tool inclinometer within its "
            f"range (roll +-{_deg(tilt_range[0])}, pitch +-{_deg(tilt_range[1])}; "
            "inclinometer.axes.*.range_rad of the station config): mount the sensor so that it "
            "reads about 0 in the robot's working orientation")
    return q[ok]


def _deg(r) -> str:
    return "any" if r is None else f"{np.degrees(r):.0f} deg"


def reference_pose(robot, xi, qm_range=None, seed: int = 0, tilt_range=None) -> np.ndarray:
    """Actuator values of the reference point (module docstring); with ``tilt_range``
    (:func:`readable`) where the tool inclinometer reads."""
    pool = safe_pool(robot, xi, np.random.default_rng(seed), qm_range=qm_range,
                     tilt_range=tilt_range)
    p = robot.frames(pool, xi)[:, :3, 3]
    target = p.mean(axis=0)
    target[2] = max(target[2], FLOOR_MARGIN + 0.1)
    for i in np.argsort(np.linalg.norm(p - target, axis=1))[:20]:
        try:
            q = robot.move_to(pool[i], target, xi)
        except UnreachablePose:
            continue
        box = joint_box(robot, qm_range)
        if np.all((q >= box[:, 0]) & (q <= box[:, 1])) and readable(robot, xi, q,
                                                                     tilt_range)[0]:
            return q
    return pool[int(np.argmin(np.linalg.norm(p - target, axis=1)))]


def path_clear(robot, xi, q0, q1, margin: float = PATH_MARGIN, steps: int = 24) -> bool:
    """True where the motion ``q0 -> q1`` (every axis at one speed) keeps the tool origin
    ``margin`` above the floor."""
    d = np.asarray(q1, dtype=float) - np.asarray(q0, dtype=float)
    s = np.linspace(0.0, np.max(np.abs(d)), steps)[:, None]
    q = q0 + np.sign(d) * np.minimum(np.abs(d), s)
    return bool(np.all(robot.frames(q, xi)[:, 2, 3] >= margin))


def identifiable(method: str, robot, xi, pool, reference_qm) -> tuple[str, ...]:
    """The parameters ``method`` identifies on ``robot`` over ``pool`` (QR analysis)."""
    model = pose_design.pool_model(method, robot, xi, pool, reference_qm=reference_qm)
    from calibration import design as dz

    return _free(robot, dz.pose_information(model, model.x0, pose_design.DEFAULT_NOISE).names)


def _free(robot, names) -> tuple[str, ...]:
    """The identifiable ``names`` the session calibrates: without the robot file's
    ``fixed``, with the draw-wire's zero offset (the session's zero is a reading)."""
    return tuple(n for n in names if n not in robot.fixed) + ("distance_off",)


def minimum_count(method: str, robot, xi, reference_qm, seed: int = 0) -> int:
    """Eq. 60 over the identifiable set of ``method`` on ``robot``."""
    pool = safe_pool(robot, xi, np.random.default_rng(seed))
    return minimum_poses(len(identifiable(method, robot, xi, pool, reference_qm)),
                         ROWS[method])


def plan(method: str, robot, xi, reference_qm, req, *, qm_range=None, start_qm=None,
         tilt_range=None):
    """``(targets, qm, use, design)`` in visiting order: ``req.count`` fit poses (default
    the margin times eq. 60; ``req.design`` ``"optimal"`` or ``"random"``) and
    ``req.validation`` held out (default a fifth, at least 3), all safe (module
    docstring); held-out poses are drawn at random from the pool. ``design`` is the
    predicted accuracy of the fit poses kept (:meth:`station.planning.pose_design.Design.as_record`)."""
    if method not in ROWS:
        raise CalibrationError(f"{method} is not planned for a robot file at the station "
                               f"(sessions: {', '.join(ROWS)})")
    rng = np.random.default_rng(req.seed)
    ref = np.asarray(reference_qm, dtype=float)
    anchor = robot.frames(ref, xi)[0, :3, 3]
    pool = safe_pool(robot, xi, rng, qm_range=qm_range, anchor=anchor, tilt_range=tilt_range)
    model = pose_design.pool_model(method, robot, xi, pool, reference_qm=ref)
    from calibration import design as dz

    info = dz.pose_information(model, model.x0, pose_design.DEFAULT_NOISE)
    n_min = minimum_poses(len(_free(robot, info.names)), ROWS[method])
    count = req.count or int(np.ceil(req.margin * n_min))
    n_val = req.validation if req.validation is not None else max(3, count // 5)
    if req.design not in pose_design.DESIGNS:
        raise CalibrationError(f"unknown design {req.design!r} (known: "
                               f"{', '.join(pose_design.DESIGNS)})")
    for extra in SPARE:          # some ways there come near the floor: more to choose from
        spare = int(np.ceil(extra * count))
        if 2 * (spare + 4 * n_val) > len(pool):     # a pool that leaves the design a choice
            draws = int(POOL * 2 * (spare + 4 * n_val) / len(pool)) + 1
            pool = safe_pool(robot, xi, rng, count=draws, qm_range=qm_range, anchor=anchor,
                             tilt_range=tilt_range)
            model = pose_design.pool_model(method, robot, xi, pool, reference_qm=ref)
            info = dz.pose_information(model, model.x0, pose_design.DEFAULT_NOISE)
        out_q, out_use, n = _visit(robot, xi, pool, info, req, rng, spare, n_val, count, ref,
                                   start_qm)
        if n == {"fit": count, "validation": n_val}:
            break
    else:
        raise CalibrationError(f"only {n['fit']} of {count} poses to fit and {n['validation']} "
                               f"of {n_val} held out of {robot.name} can be reached without the "
                               "tool coming near the floor")
    qm = np.array(out_q)
    kept = [int(np.flatnonzero(np.all(pool == q, axis=1))[0]) for q in qm]
    fit_idx = np.array([i for i, u in zip(kept, out_use) if u == "fit"])
    val_qm = qm[[u == "validation" for u in out_use]]
    return robot.fk(qm, xi), qm, out_use, _design_record(req.design, robot, model, info,
                                                         fit_idx, val_qm)


def _visit(robot, xi, pool, info, req, rng, spare, n_val, count, ref, start_qm):
    """``spare`` fit candidates (D-optimal or random) and ``4 n_val`` held-out ones from
    ``pool``, visited in the travel order, a blocked way skipped for the next clear one,
    until ``count`` and ``n_val`` are reached: ``(qm list, use list, counts)``."""
    from calibration import design as dz

    fit = list(dz.d_optimal(info, spare) if req.design == "optimal"
               else rng.choice(len(pool), size=spare, replace=False))
    rest = np.setdiff1d(np.arange(len(pool)), fit)
    val = list(rng.choice(rest, size=4 * n_val, replace=False))
    out_q, out_use, n = travel(robot, xi, pool, fit, val, ref if start_qm is None else start_qm,
                               count, n_val, here=ref)
    return out_q, out_use, n


def travel(robot, xi, pool, fit, val, start, n_fit: int, n_val: int, here=None):
    """The ``fit`` and ``val`` candidates of ``pool`` (indices) in the travel order from
    ``start`` (:func:`calibration.planning.order_for_travel`), each way checked from the
    last pose kept (:func:`path_clear` at ``xi``; the first from ``here``, default
    ``start``), a blocked way skipped for the next clear one, until ``n_fit`` and
    ``n_val``: ``(qm list, use list, counts)``."""
    chosen = list(fit) + list(val)
    use = ["fit"] * len(fit) + ["validation"] * len(val)
    todo = list(planning.order_for_travel(pool[chosen], start=start))
    here = np.asarray(start if here is None else here, dtype=float)
    out_q, out_use, n = [], [], {"fit": 0, "validation": 0}
    want = {"fit": n_fit, "validation": n_val}
    while todo and n != want:        # the travel order; a blocked way: the next clear one
        todo = [k for k in todo if n[use[k]] < want[use[k]]]
        k = next((k for k in todo if path_clear(robot, xi, here, pool[chosen[k]])), None)
        if k is None:
            break
        todo.remove(k)
        here = pool[chosen[k]]
        out_q.append(here)
        out_use.append(use[k])
        n[use[k]] += 1
    return out_q, out_use, n


def _design_record(design: str, robot, model, info, fit_idx, val_qm) -> dict:
    """The plan's predicted accuracy (:class:`station.planning.pose_design.Design`) for the fit
    poses kept, the held-out error predicted at the planned held-out poses."""
    from calibration import design as dz

    held = {}
    hm = pose_design.heldout_map(robot, model, info, val_qm)
    if hm is not None:
        J, what, unit = hm
        held = {"what": what, "unit": unit,
                "rms": pose_design.heldout_rms(J, dz.covariance(info, fit_idx))}
    return pose_design.Design(fit_idx, design, info.names, dz.cramer_rao(info, fit_idx),
                              dz.observability(info, fit_idx), held).as_record()


def point_to_point_rms(robot, xi_a, xi_b, *, pairs: int = 1000, seed: int = 0,
                       qm_range=None) -> float:
    """RMS difference (m) between models ``xi_a`` and ``xi_b`` of the distances between
    the tool origins of ``pairs`` pairs of random poses within the limits (the middle
    80 %, tool above the floor by ``xi_b``): a frame-free measure of a calibration."""
    rng = np.random.default_rng(seed)
    q = safe_pool(robot, np.asarray(xi_b, dtype=float)[:robot.n_params], rng,
                  count=8 * pairs, qm_range=qm_range)[:2 * pairs]
    half = len(q) // 2

    def dist(xi):
        p = robot.frames(q, np.asarray(xi, dtype=float)[:robot.n_params])[:, :3, 3]
        return np.linalg.norm(p[:half] - p[half:2 * half], axis=1)

    return float(np.sqrt(np.mean((dist(xi_a) - dist(xi_b)) ** 2)))
