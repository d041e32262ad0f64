"""What a session measures: the reference pose and the IK-planned poses of a method.

Pure planning (no devices): the session asks for the reference pose an operator
should capture, then for the poses to drive to, planned with the IK of the best
model it has, within the robot's joint limits, counted by eq. 60 and ordered to
keep actuator travel short. Each planned pose is ``fit`` or ``validation``
(held out: measured, never fitted, used to check the result).

The PM wrist is planned in two rounds. The report's nominal wrist cannot reach
even ``X = 0`` (its rods are too short), so its IK cannot plan the real robot's
poses. Round one, the *scout*, plans a few poses close to the home pose with
the nominal whose rod length explains the home reading
(:func:`calibration.pm_start.feasible_start`); after they are measured, round
two plans the full workspace with the start model fitted to them
(:func:`calibration.pm_start.robust_start`).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from calibration import planning
from calibration.errors import CalibrationError
from calibration.identifiability import minimum_poses
from calibration.methods import METHODS, MethodData
from calibration.methods.sm_distance_tilt import reframe_nominal
from calibration.robots import get_robot

# where the operator puts the end effector for the reference (report 7.2 and 7.5)
SM_REFERENCE_POINT = np.array([1.0, 1.0, 0.0, 0.2])   # relative to the base offset
SM_BASE_ORIGIN = np.array([0.5, 1.0, 0.8, 0.0])       # absolute, elbow -1
# N_R and p of each method (brief section 3) for the pose count of eq. 60
NR_P = {"sm-distance": (9, 1), "sm-distance-tilt": (13, 2), "pm-ik": (8, 3), "pm-fk": (8, 3),
        "pm-tilt": (10, 2)}
SESSION_METHODS = tuple(NR_P)
PM_SCOUT_COUNT = 12
PM_SCOUT_SCALE = 0.3          # fraction of the report's +-20 deg box for the scout round


@dataclass(frozen=True)
class PlannedPose:
    """One pose to measure: ``qm`` actuator targets, ``target`` the generalized
    coordinates planned, ``use`` ``"fit"`` or ``"validation"``, ``round`` (0; PM scout 0,
    main 1) and ``index`` its place in the session's whole plan."""

    index: int
    qm: tuple[float, ...]
    target: tuple[float, ...]
    use: str = "fit"
    round: int = 0

    def record(self) -> dict:
        return {"index": self.index, "qm": list(self.qm), "target": list(self.target),
                "use": self.use, "round": self.round}

    @classmethod
    def from_record(cls, r: dict) -> "PlannedPose":
        return cls(int(r["index"]), tuple(r["qm"]), tuple(r["target"]), r.get("use", "fit"),
                   int(r.get("round", 0)))


@dataclass
class PlanRequest:
    """How many poses (None: eq. 60 times ``margin``) and held-out poses, and the seed."""

    count: int | None = None
    validation: int | None = None
    seed: int = 0
    margin: float = 2.0
    components: tuple[str, ...] = ("alpha", "beta", "gamma")
    notes: list[str] = field(default_factory=list)


def check_method(method: str) -> None:
    if method not in METHODS:
        raise CalibrationError(f"unknown method {method!r} (known: {', '.join(METHODS)})")
    if method not in SESSION_METHODS:
        raise CalibrationError(
            f"method {method} needs measurements this station does not take unattended "
            f"({'a pose tracker' if method == 'sm-full-pose' else 'guided touching'}); record "
            f"its trace elsewhere and calibrate it with app.py batch. Station sessions "
            f"support: {', '.join(SESSION_METHODS)}")


def minimum_count(method: str, components=None) -> int:
    nr, p = NR_P[method]
    if method == "pm-fk" and components:
        p = len(components)
    return minimum_poses(nr, p)


def reference_pose(method: str, nominal) -> tuple[np.ndarray | None, str | None, str]:
    """``(qm, role, instructions)`` of the reference step; qm None where the method has none."""
    robot = get_robot(METHODS[method].robot)
    if method == "sm-distance-tilt":
        qm = robot.ik(SM_BASE_ORIGIN, nominal, elbow=-1)
        return qm, "base-origin", (
            "Jog the end effector to where the base origin of the calibration should be "
            "(inside the working area, about 0.5 m out, 1 m along the rail, 0.8 m up), attach "
            "the draw-wire cable to it there and capture: the draw-wire is zeroed and the "
            "actuator values recorded. theta0, a0 and q1_off will refer to this point.")
    if method == "sm-distance":
        off = np.r_[robot.base_offset(nominal), 0.0]
        qm = robot.ik(SM_REFERENCE_POINT + off, nominal)
        return qm, "reference-point", (
            "Jog the end effector to the reference point, attach the draw-wire cable there "
            "and capture: the draw-wire is zeroed and the actuator values recorded.")
    return None, None, ("The wrist needs no reference. Check that the inclinometer is "
                        "mounted flat on the platform with its x axis along the platform's x "
                        "axis: at the home pose it should read roll and pitch near 0.")


def plan_sm(method: str, nominal, reference_qm, req: PlanRequest) -> list[PlannedPose]:
    robot = get_robot("agebot-sm")
    rng = np.random.default_rng(req.seed)
    count = req.count or int(np.ceil(req.margin * minimum_count(method)))
    n_val = req.validation if req.validation is not None else max(3, count // 5)
    total = count + n_val
    if method == "sm-distance-tilt":
        framed = reframe_nominal(robot, nominal, reference_qm)
        elbow = robot.elbow_of(reference_qm, nominal)
        plan = planning.sample_poses(robot, framed, planning.box_array(robot, planning.SM_BOX_7_5),
                                     total, rng, ik_options={"elbow": elbow})
    else:
        off = np.r_[robot.base_offset(nominal), 0.0]
        plan = planning.sample_poses(robot, nominal, planning.box_array(robot, planning.SM_BOX_7_1,
                                                                        off), total, rng)
    return _finish(robot, plan.targets, plan.qm, n_val, rng, reference_qm, 0, 0)


def plan_pm_scout(home_qm, home_orientation, req: PlanRequest) -> list[PlannedPose]:
    """Round one of the wrist: poses near home with the reach-corrected nominal."""
    from calibration.pm_start import feasible_start

    robot = get_robot("agebot-pm")
    rng = np.random.default_rng(req.seed)
    xi = feasible_start(robot, np.atleast_2d(home_qm), np.atleast_2d(home_orientation),
                        robot.nominal)
    box = planning.box_array(robot, planning.PM_BOX) * PM_SCOUT_SCALE
    plan = planning.sample_poses(robot, xi, box + np.asarray(home_orientation)[:, None],
                                 PM_SCOUT_COUNT, rng)
    return _finish(robot, plan.targets, plan.qm, 0, rng, home_qm, 0, 0)


def pm_start_model(qm, readings, method: str, components) -> np.ndarray:
    """The start model fitted to measured poses (round two's planning model)."""
    from calibration.pm_start import robust_start

    robot = get_robot("agebot-pm")
    if method == "pm-tilt":
        data = MethodData(qm=qm, channels={"tilt": readings})
        return robust_start(robot, data, np.r_[robot.nominal, 0.0, 0.0])[:robot.n_params]
    data = MethodData(qm=qm, channels={"orientation": readings}, components=tuple(components))
    return robust_start(robot, data, robot.nominal, tuple(components))


def plan_pm_main(xi_start, method: str, first_index: int, last_qm, req: PlanRequest,
                 already: int) -> list[PlannedPose]:
    """Round two of the wrist: the report's +-20 deg box with the fitted start model."""
    robot = get_robot("agebot-pm")
    rng = np.random.default_rng(req.seed + 1)
    comps = req.components if method == "pm-fk" else None
    count = req.count or int(np.ceil(req.margin * minimum_count(method, comps)))
    count = max(count - already, 1)
    n_val = req.validation if req.validation is not None else max(3, (count + already) // 5)
    plan = planning.sample_poses(robot, xi_start, planning.box_array(robot, planning.PM_BOX),
                                 count + n_val, rng)
    return _finish(robot, plan.targets, plan.qm, n_val, rng, last_qm, first_index, 1)


def _finish(robot, targets, qm, n_val, rng, start_qm, first_index, rnd) -> list[PlannedPose]:
    """Pick held-out poses at random and order for short travel (the IK already
    refused poses outside the joint limits: ``AgebotSM.ik`` checks them)."""
    use = np.array(["fit"] * len(qm), dtype=object)
    if n_val:
        use[rng.choice(len(qm), size=n_val, replace=False)] = "validation"
    order = planning.order_for_travel(qm, start=start_qm)
    return [PlannedPose(first_index + k, tuple(float(v) for v in qm[i]),
                        tuple(float(v) for v in targets[i]), str(use[i]), rnd)
            for k, i in enumerate(order)]
