"""Poses for a point instrument (a laser tracker, a motion capture): ``sm-markers`` at the
station, for a URDF robot whose tool carries points the instrument measures in its own
frame (:mod:`calibration.methods.sm_markers`).

A pose is planned only where every point is *visible* (:class:`Sight`): inside the
instrument's measuring volume (an axis-aligned box in its frame) and facing it (the
angle between the point's outward direction and its line of sight to the
instrument's viewpoint at most ``max_angle``), as the current model (the robot's
parameters, the instrument's frame ``base_*``, the points) predicts. Candidates are
drawn in joint space, in the joint limits shrunk by :data:`MARGIN` of each range (the
station config's limits where narrower), scaled about the start pose (home: the URDF's
zero, :func:`home_qm`) by the round's ``scale``, and kept where the tool is
:data:`~station.planning.serial_plan.FLOOR_MARGIN` above the floor of the base link
(:func:`station.planning.serial_plan.safe_pool`) and every point is visible. The fit
poses are the D-optimal choice for the parameters given the poses already measured
(:func:`station.planning.pose_design.choose`, the sm-markers Jacobian of the current
model at the candidates), the held-out ones drawn at random; they are visited in the
travel order and every motion keeps the tool above the floor
(:func:`station.planning.serial_plan.path_clear`), a blocked way skipped for the next.

Rounds, as the arm's (:mod:`station.planning.arm_rounds`): the instrument's frame and the
points are not known before anything is measured, so round 0 is a *scout*
(:func:`scout`): a few poses in a small box about home (``SCOUT_SCALE`` of the box),
varied in every joint, from which :func:`calibration.methods.sm_markers.register`
estimates the frame and the points (the same reference-free start as an imported
trace's); visibility is checked only loosely there (every point inside the volume where
a frame is guessed). Later rounds (:func:`plan` with a larger ``scale``) use the model
fitted so far.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from calibration import planning
from calibration.errors import CalibrationError
from calibration.identifiability import minimum_poses
from calibration.methods.sm_markers import FRAME_PARAMS
from station.planning import pose_design
from station.planning.arm_rounds import EARLY_SHARE, SCOUT_SCALE
from station.planning.serial_plan import FLOOR_MARGIN, POOL, SPARE, joint_box, safe_pool, \
    travel

METHOD = "sm-markers"
MARGIN = 0.05            # share of each joint's range kept clear of its limits
SEEN_EVERYWHERE = 0.01   # m: a point this close to the tip's origin has no outward side
SCOUT_POSES = 8          # the scout's poses at least (register needs 3; a refit more)
MAX_DRAWS = 20 * POOL    # candidates drawn at most per plan where few are visible
#: why a candidate is left out, for the error that says which failed most
FAILS = {"volume": "a point outside the measuring volume",
         "facing": "a point turned away from the instrument beyond max_angle",
         "floor": f"the tool less than {FLOOR_MARGIN} m above the base's floor"}


@dataclass(frozen=True)
class Sight:
    """What the instrument sees, in its own frame (m, rad).

    volume_min, volume_max: ``(3,)`` corners of the measuring volume (axis-aligned box).
    viewpoint: ``(3,)`` where the line of sight comes from (a tracker's head, the centre
               of a motion capture's cameras).
    max_angle: largest angle between a point's outward direction and the direction from
               the point to the viewpoint (a reflector's acceptance angle).
    outward:   ``(M, 3)`` outward directions in the tip link's frame; None: each point's
               own direction from the tip link's origin (a point closer than
               :data:`SEEN_EVERYWHERE` to it is seen from everywhere)."""

    volume_min: tuple
    volume_max: tuple
    viewpoint: tuple
    max_angle: float
    outward: tuple | None = None

    def __post_init__(self):
        for name in ("volume_min", "volume_max", "viewpoint"):
            v = np.asarray(getattr(self, name), dtype=float).reshape(-1)
            if v.shape != (3,) or not np.all(np.isfinite(v)):
                raise CalibrationError(f"sight: {name} must be three finite numbers (m)")
            object.__setattr__(self, name, tuple(float(c) for c in v))
        if not all(a < b for a, b in zip(self.volume_min, self.volume_max)):
            raise CalibrationError("sight: volume_min must be below volume_max on every axis")
        if not 0.0 < float(self.max_angle) <= math.pi:
            raise CalibrationError("sight: max_angle must be in (0, pi] rad")
        object.__setattr__(self, "max_angle", float(self.max_angle))
        if self.outward is not None:
            d = np.asarray(self.outward, dtype=float).reshape(-1, 3)
            object.__setattr__(self, "outward", tuple(tuple(float(c) for c in r) for r in d))


def sight_checks(robot, xi, points, sight: Sight, qm) -> tuple[np.ndarray, np.ndarray]:
    """``(inside, facing)``, each ``(m, M)`` bool: every point inside the volume, and
    facing the viewpoint, at each pose ``qm (m, n)`` (``xi``: the robot's parameters with
    its base in the instrument's frame; ``points (M, 3)`` in the tip link's frame)."""
    qm = np.atleast_2d(np.asarray(qm, dtype=float))
    u = np.asarray(points, dtype=float).reshape(-1, 3)
    T = robot.frames(qm, np.asarray(xi, dtype=float)[:robot.n_params])
    R = T[:, :3, :3]
    P = T[:, None, :3, 3] + np.einsum("mij,kj->mki", R, u)
    inside = np.all((P >= np.asarray(sight.volume_min)) & (P <= np.asarray(sight.volume_max)),
                    axis=2)
    d = u if sight.outward is None else np.asarray(sight.outward, dtype=float)
    if d.shape != u.shape:
        raise CalibrationError(f"sight: {len(d)} outward directions for {len(u)} points")
    size = np.linalg.norm(d, axis=1)
    everywhere = size < (SEEN_EVERYWHERE if sight.outward is None else 1e-12)
    n = np.einsum("mij,kj->mki", R, d / np.where(everywhere, 1.0, size)[:, None])
    los = np.asarray(sight.viewpoint) - P
    dist = np.linalg.norm(los, axis=2)
    cos = np.einsum("mki,mki->mk", n, los) / np.where(dist > 0, dist, 1.0)
    facing = everywhere[None, :] | (dist == 0) | (cos >= math.cos(sight.max_angle) - 1e-12)
    return inside, facing


def visible(robot, xi, points, sight: Sight, qm) -> np.ndarray:
    """``(m, M)`` bool: each point inside the measuring volume and facing the viewpoint
    at each pose (:func:`sight_checks`)."""
    inside, facing = sight_checks(robot, xi, points, sight, qm)
    return inside & facing


def limit_box(robot, qm_range=None, margin: float = MARGIN) -> np.ndarray:
    """``(n, 2)`` the joint limits shrunk by ``margin`` of each range, within the station
    config's ``qm_range`` where narrower."""
    lim = np.array(robot.limits, dtype=float)
    span = lim[:, 1] - lim[:, 0]
    box = np.column_stack([lim[:, 0] + margin * span, lim[:, 1] - margin * span])
    if qm_range is not None:
        r = np.asarray(qm_range, dtype=float)
        box = np.column_stack([np.maximum(box[:, 0], r[:, 0]), np.minimum(box[:, 1], r[:, 1])])
    bad = np.flatnonzero(box[:, 0] > box[:, 1])
    if bad.size:
        raise CalibrationError(f"joint {bad[0] + 1} of {robot.name} has no room inside its "
                               f"limits less {margin:.0%} of its range and the config's limits")
    return box


def home_qm(robot, qm_range=None, margin: float = MARGIN) -> np.ndarray:
    """The URDF's zero configuration clipped into the limits with the margin."""
    box = limit_box(robot, qm_range, margin)
    return np.clip(np.zeros(robot.n_actuators), box[:, 0], box[:, 1])


def pose_box(robot, qm_range=None, *, centre=None, scale: float = 1.0,
             margin: float = MARGIN) -> np.ndarray:
    """``(n, 2)``: :func:`limit_box` scaled by ``scale`` about ``centre`` (home where
    None; brought inside the box first)."""
    box = limit_box(robot, qm_range, margin)
    c = home_qm(robot, qm_range, margin) if centre is None else np.asarray(centre, dtype=float)
    return planning.scale_box(box, float(scale), np.clip(c, box[:, 0], box[:, 1]))


class _Boxed:
    """``robot`` with limits whose part :func:`~station.planning.serial_plan.safe_pool`
    draws from (:func:`~station.planning.serial_plan.joint_box`: their middle) is ``box``."""

    def __init__(self, robot, box):
        self._robot = robot
        share = float(np.diff(joint_box(_Unit())[0])[0])      # the middle share it keeps
        mid, half = box.mean(axis=1), 0.5 * (box[:, 1] - box[:, 0]) / share
        self.limits = np.column_stack([mid - half, mid + half])

    def __getattr__(self, name):
        return getattr(self._robot, name)


class _Unit:
    limits = np.array([[0.0, 1.0]])


def base_model(robot, xi) -> np.ndarray:
    """The robot's parameters ``xi`` with the instrument's frame left out (poses in the
    base link's frame: its floor is ``z = 0``)."""
    x = np.array(xi, dtype=float)[:robot.n_params]
    x[[robot.index(name) for name in FRAME_PARAMS]] = 0.0
    return x


def draw(robot, xi, points, sight, box, rng, count: int, *, volume_only: bool = False):
    """Up to ``count`` candidates in ``box`` above the floor with every point visible
    (``sight`` None: not checked; ``volume_only``: inside the volume only):
    ``(qm (k, n), tally)``, tally the poses drawn and how many failed each condition."""
    try:
        q = safe_pool(_Boxed(robot, box), base_model(robot, xi), rng, count=count)
    except CalibrationError:            # none above the floor: said with the others below
        q = np.zeros((0, robot.n_actuators))
    q = np.clip(q, box[:, 0], box[:, 1])
    tally = {"drawn": count, "floor": count - len(q), "volume": 0, "facing": 0}
    if sight is None or not len(q):
        return q, tally
    inside, facing = sight_checks(robot, xi, points, sight, q)
    ok_in, ok_face = inside.all(axis=1), facing.all(axis=1)
    tally["volume"], tally["facing"] = int(np.sum(~ok_in)), int(np.sum(~ok_face))
    return q[ok_in if volume_only else ok_in & ok_face], tally


def too_few(robot, tally, got: int, need: int) -> CalibrationError:
    """The one-line error of a pool with fewer visible candidates than needed."""
    worst = max(FAILS, key=lambda k: tally[k])
    return CalibrationError(
        f"only {got} of {tally['drawn']} poses of {robot.name} drawn within its joint limits "
        f"keep every point visible, {need} needed: most failed on {worst} ({tally[worst]} "
        f"poses with {FAILS[worst]}; volume {tally['volume']}, facing {tally['facing']}, "
        f"floor {tally['floor']}): widen the measuring volume or view_angle_deg, move the "
        "instrument or the points, or check the instrument's frame")


def pool(robot, xi, points, sight, box, rng, want: int, need: int, *,
         volume_only: bool = False) -> np.ndarray:
    """At least ``need`` visible candidates (:func:`draw`), ``want`` where the draws allow
    (at most :data:`MAX_DRAWS`); :func:`too_few` where fewer than ``need``."""
    q, tally = draw(robot, xi, points, sight, box, rng, POOL, volume_only=volume_only)
    if len(q) < want:
        more = MAX_DRAWS if not len(q) else min(MAX_DRAWS, int(POOL * want / len(q)) + 1)
        q2, t2 = draw(robot, xi, points, sight, box, rng, more, volume_only=volume_only)
        q, tally = np.vstack([q, q2]), {k: tally[k] + t2[k] for k in tally}
    if len(q) < need:
        raise too_few(robot, tally, len(q), need)
    return q[:max(want, POOL)]


def plan(robot, xi, points, sight: Sight, req, *, qm_range=None, start_qm=None,
         scale: float = 1.0, measured_qm=(), margin: float = MARGIN, noise=None):
    """``(qm (k, n), use, design)`` in visiting order: ``req.count`` fit poses (None: the
    request's margin times eq. 60 over the parameters the pool identifies) chosen
    D-optimally (``req.design``; ``req.target`` grows them) given ``measured_qm`` (the
    fit poses of earlier rounds), and ``req.validation`` held out at random (None: a
    fifth, at least 3), every point visible (module docstring). ``xi``: the robot's
    parameters with the instrument's frame; ``points (M, 3)`` on the tool; the box is
    the limits less ``margin`` (and ``qm_range``) scaled by ``scale`` about ``start_qm``
    (home where None), where the travel starts. ``design``: the predicted accuracy of
    the measured and planned fit poses (:meth:`~station.planning.pose_design.Design.as_record`)."""
    if req.design not in pose_design.DESIGNS:
        raise CalibrationError(f"unknown design {req.design!r} (known: "
                               f"{', '.join(pose_design.DESIGNS)})")
    u = _points(points)
    xi = np.asarray(xi, dtype=float)[:robot.n_params]
    box, start = _start_box(robot, qm_range, start_qm, scale, margin)
    measured = np.asarray(measured_qm, dtype=float).reshape(-1, robot.n_actuators)
    return _planned(robot, xi, u, sight, req, box, start, measured, noise)


def scout(robot, xi_guess, points_guess, sight: Sight | None, req, *, frame_known: bool = True,
          qm_range=None, start_qm=None, scale: float = SCOUT_SCALE, count: int | None = None,
          margin: float = MARGIN, noise=None):
    """Round 0, before the instrument's frame and the points are known: ``count`` fit
    poses (default :data:`SCOUT_POSES`, or an eighth of ``req.count`` where more, as the
    arm's scout) in the box scaled by ``scale`` (``SCOUT_SCALE``) about ``start_qm``
    (home), above the floor, the D-optimal choice (``req.design``) for the parameters of
    the guess (``xi_guess``; ``points_guess (M, 3)``, None: one point at the tip's
    origin), so that every joint moves and :func:`calibration.methods.sm_markers.register`
    can place the frame and the points. Visibility is loose: every point inside the
    volume where ``frame_known`` (the guess places the instrument), else not checked.
    Returns ``(qm, use, design)`` as :func:`plan` (every pose ``"fit"``)."""
    import dataclasses

    n = count or max(SCOUT_POSES, math.ceil((req.count or 0) / EARLY_SHARE))
    u = np.zeros((1, 3)) if points_guess is None else _points(points_guess)
    xi = np.asarray(xi_guess, dtype=float)[:robot.n_params]
    box, start = _start_box(robot, qm_range, start_qm, scale, margin)
    req = dataclasses.replace(req, count=n, validation=0, target=None)
    return _planned(robot, xi, u, sight if frame_known else None, req, box, start,
                    np.zeros((0, robot.n_actuators)), noise, volume_only=True)


def _points(points) -> np.ndarray:
    u = np.asarray(points, dtype=float).reshape(-1, 3)
    if not len(u) or not np.all(np.isfinite(u)):
        raise CalibrationError("sm-markers plans with the points on the tool: (M, 3) finite")
    return u


def _start_box(robot, qm_range, start_qm, scale, margin):
    """``(box, start)``: :func:`pose_box` about the start (home where None)."""
    start = (home_qm(robot, qm_range, margin) if start_qm is None
             else np.asarray(start_qm, dtype=float))
    return pose_box(robot, qm_range, centre=start, scale=scale, margin=margin), start


def fit_count(robot, x_plan, qm, margin: float, noise=None) -> int:
    """``margin`` times eq. 60 over the parameters sm-markers identifies over ``qm``."""
    from calibration import design as dz

    model = pose_design.pool_model(METHOD, robot, x_plan, qm)
    info = dz.pose_information(model, model.x0, noise or pose_design.DEFAULT_NOISE)
    rows = 3 * ((len(x_plan) - robot.n_params) // 3)
    return int(np.ceil(margin * minimum_poses(len(info.names), rows)))


def _planned(robot, xi, u, sight, req, box, start, measured, noise, *, volume_only=False):
    """The plan in ``box`` (:func:`plan`, :func:`scout`)."""
    rng = np.random.default_rng(req.seed)
    x_plan = np.r_[xi, u.reshape(-1)]
    count = req.count
    if not count:
        first = pool(robot, xi, u, sight, box, rng, 1, 1, volume_only=volume_only)
        count = fit_count(robot, x_plan, np.vstack([measured, first]), req.margin, noise)
    n_val = req.validation if req.validation is not None else max(3, count // 5)
    want = 2 * (math.ceil(SPARE[0] * count) + 4 * n_val)   # a pool that leaves a choice
    cand = pool(robot, xi, u, sight, box, rng, want, count + n_val, volume_only=volume_only)
    for extra in (1.0,) + SPARE:    # some ways there come near the floor: spares
        spare = min(math.ceil(extra * count), len(cand) - n_val)
        fit, _ = pose_design.choose(METHOD, robot, x_plan, cand, spare, measured=measured,
                                    design=req.design, rng=rng, noise=noise,
                                    target=req.target)
        goal = count + max(0, len(fit) - spare)      # a target grew the choice
        rest = np.setdiff1d(np.arange(len(cand)), fit)
        val = rng.choice(rest, size=min(4 * n_val, len(rest)), replace=False)
        qm, use = _visit(robot, xi, cand, fit, val, start, goal, n_val)
        if (use.count("fit"), use.count("validation")) == (goal, n_val):
            return qm, use, _record(robot, x_plan, qm, use, measured, req, noise)
        if spare >= len(cand) - n_val:
            break
    raise CalibrationError(f"only {use.count('fit')} of {goal} poses to fit and "
                           f"{use.count('validation')} of {n_val} held out of {robot.name} "
                           "can be reached without the tool coming near the floor")


def _visit(robot, xi, cand, fit, val, start, n_fit: int, n_val: int):
    """The ``fit`` and ``val`` candidates in the travel order from ``start``, each way
    checked above the floor of the base link (:func:`~station.planning.serial_plan.travel`),
    until ``n_fit`` and ``n_val``: ``(qm (k, n), use list)``."""
    out_q, out_use, _ = travel(robot, base_model(robot, xi), cand, np.asarray(fit, dtype=int),
                               np.asarray(val, dtype=int), start, n_fit, n_val)
    return np.array(out_q).reshape(-1, robot.n_actuators), out_use


def _record(robot, x_plan, qm, use, measured, req, noise) -> dict:
    """The predicted accuracy of the measured and the planned fit poses, the held-out
    error at the planned held-out poses (:func:`~station.planning.pose_design.choose` of
    them all)."""
    kind = np.array(use)
    fit_q, val_q = qm[kind == "fit"], qm[kind == "validation"]
    _, design = pose_design.choose(METHOD, robot, x_plan, fit_q, len(fit_q), measured=measured,
                                   design=req.design, rng=np.random.default_rng(0),
                                   noise=noise, heldout_qm=val_q if len(val_q) else None)
    return design.as_record()
