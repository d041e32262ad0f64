"""The wrist's growing box: scout near home, fit, widen only as far as the model has earned.

The report's nominal wrist is far from a real one (a2 60 % off, gear ratios up to
40 %, offsets of centimetres): poses planned with its IK put a real wrist 50-180
deg away from where they were meant to go. So the session never trusts a model
further than it has been seen to hold:

Before each round the start model must explain the recorded readings (RMS at most
:data:`FIT_RMS_DEG`): a model that cannot has earned no wider box.

1. **Scout** (round 0): :data:`SCOUT_COUNT` poses within :data:`SCOUT_DEG` of the
   home orientation, planned *relative to home*: the nominal IK gives the change
   of the actuators from home, which is right to first order whatever the
   offsets (an absolute nominal IK is not: the offsets alone move a rod by
   centimetres).
2. **Fit** the start model (:func:`calibration.pm_start.robust_start_detail`, in IK
   space: defined wherever the rods reach, no assembly mode to lose) to every
   pose recorded so far.
3. **Widen**: the next round's box is the region measured so far (largest fitted
   angle) times :data:`GROW`, at most the report's +-20 deg box; growing rounds
   have :data:`ROUND_COUNT` poses; the round that reaches +-20 deg is the final
   one and holds the remaining fit poses (at least :data:`ROUND_COUNT`: where the
   growing rounds used up the requested count, the session measures more) and the
   held-out ones.

Every planned pose is checked against the current model before it is sent: the
IK reaches it, the sliders stay within their stroke (station config
``[envelope] qm_min, qm_max``), the passive joints within their range
(:func:`calibration.robots.agebot_pm.envelope_violation`). While executing, the
measured orientation is compared with what the current model predicts for the
actuator values reached (FK); beyond :data:`TOLERANCE_DEG` the pose is not
recorded, the rest of its round is dropped and the next round is planned from
what was recorded (refit, and a smaller growth step). After :data:`MAX_TRIPS`
such stops in a row, or when the start model cannot be fitted, the session
stops (:class:`WristStopped`) with what the operator should do.
"""
from __future__ import annotations

import math

import numpy as np

from calibration import planning
from calibration.errors import CalibrationError, StationError
from calibration.methods import MethodData
from calibration.pm_start import feasible_start, robust_start_detail
from calibration.robots import get_robot
from calibration.robots.agebot_pm import envelope_violation, gravity_tilt, rot_xyz
from station.planning.pose_design import POOL_FACTOR, choose
from station.planning.arm_plan import _finish
from station.fitting.pose_count import minimum_count
from station.planning.request import PlanRequest
from station.recording.planned_pose import PlannedPose

PM_SCOUT_COUNT = 12
SCOUT_COUNT = PM_SCOUT_COUNT
SCOUT_DEG = 4.0          # scout box half-width around home, deg
GROW = 1.6               # next box = GROW x the region measured so far
BOX_DEG = 20.0           # the report's box, deg
ROUND_COUNT = 4          # fit poses per growing round
TOLERANCE_DEG = 3.0      # measured vs predicted orientation, deg: beyond it the station stops
MAX_TRIPS = 3            # stops in a row before the session gives up
MIN_FIT_POSES = 6
FIT_RMS_DEG = 0.5        # the start model must explain the recorded readings this well
COMPONENTS = ("alpha", "beta", "gamma")
ADVICE = ("enter the gear ratios k1, k2, k3 (from the drives' data sheets) and the slider "
          "offsets you know as start values (app.py run --nominal k1=...), check that the "
          "orientation sensor is mounted square and its axes mapped right, then start a new "
          "session")


class WristStopped(StationError):
    """The wrist's session stopped before driving where its model cannot vouch for."""


def reach_deg(X) -> float:
    """The measured region: largest |angle| (deg) of orientations ``X (m, 3)``."""
    return float(np.degrees(np.max(np.abs(np.asarray(X, dtype=float))))) if len(X) else 0.0


class WristPlanner:
    """The growing-box plan of one wrist session (module doc).

    method:   ``pm-fk``, ``pm-ik`` or ``pm-tilt``; components: measured pm-fk components.
    request:  the session's :class:`PlanRequest` (counts, seed).
    qm_range: slider stroke ``(3, 2)`` in actuator units (None: not checked).
    """

    def __init__(self, method: str, request: PlanRequest, components=None, qm_range=None):
        self.robot = get_robot("agebot-pm")
        self.method, self.request = method, request
        self.components = tuple(components or COMPONENTS)
        self.qm_range = None if qm_range is None else np.asarray(qm_range, dtype=float)
        self.xi: np.ndarray | None = None       # the current model (None: scout, relative)
        self.mount = np.zeros(2)
        self.home: tuple[np.ndarray, np.ndarray] | None = None
        self.rounds = 0
        self.final = False                       # the +-20 deg round is planned
        self.trips = 0                           # watch stops since the last recorded round
        self.replan = False
        self._recorded = 0                       # poses recorded when the last round was planned

    # -- state from a trace's events (resume) --------------------------------------------------
    def restore(self, events) -> None:
        """Take the model, round and trips from a resumed trace's ``plan``/``envelope`` events."""
        for ev in events:
            if ev.get("kind") == "plan" and "wrist" in ev:
                w = ev["wrist"]
                self.rounds = int(w.get("round", 0)) + 1
                self.final = bool(w.get("final", False))
                self.replan = False
                if w.get("model") is not None:
                    self.xi = np.array(w["model"], dtype=float)
                    self.mount = np.array(w.get("mount", (0.0, 0.0)), dtype=float)
                if w.get("home_qm") is not None:
                    self.home = (np.array(w["home_qm"]), np.array(w["home_X"]))
            elif ev.get("kind") == "envelope":
                self.trips += 1
                self.replan = True

    def _accept(self, xi):
        def ok(X, qm):
            return envelope_violation(X, xi, qm, self.qm_range) is None
        return ok

    # -- rounds -------------------------------------------------------------------------------
    def scout(self, home_qm, home_X) -> tuple[list[PlannedPose], dict]:
        """Round 0: poses near home, planned relative to home with the reach-corrected
        nominal. Returns the poses and the plan event's ``wrist`` record."""
        robot, rng = self.robot, np.random.default_rng(self.request.seed)
        home_qm, home_X = np.asarray(home_qm, dtype=float), np.asarray(home_X, dtype=float)
        xi = feasible_start(robot, np.atleast_2d(home_qm), np.atleast_2d(home_X), robot.nominal)
        q_home = robot.ik_actuators(home_X, xi)[0]
        box = np.radians(SCOUT_DEG) * np.array([[-1.0, 1.0]] * 3) + home_X[:, None]

        def ok(X, qm):   # stroke only: the nominal's passive angles say nothing of this wrist
            return envelope_violation(X, xi, qm - q_home + home_qm, self.qm_range) is None \
                if self.qm_range is not None else True
        plan = planning.sample_poses(robot, xi, box, SCOUT_COUNT, rng, accept=ok)
        qm = plan.qm - q_home + home_qm
        self.home, self.rounds, self.final = (home_qm, home_X), 1, False
        poses = _finish(robot, plan.targets, qm, 0, rng, home_qm, 0, 0)
        return poses, {"round": 0, "box_deg": SCOUT_DEG, "final": False, "model": None,
                       "home_qm": home_qm.tolist(), "home_X": home_X.tolist()}

    def fit(self, records) -> np.ndarray:
        """Fit the start model to the recorded pose records; returns the fitted
        orientations ``(m, 3)``. Raises :class:`WristStopped` when it cannot."""
        robot = self.robot
        qm = np.array([r["qm"] for r in records], dtype=float)
        try:
            if self.method == "pm-tilt":
                data = MethodData(qm=qm, channels={"tilt": np.array([r["tilt"] for r in records])})
                start = robust_start_detail(robot, data, np.r_[robot.nominal, 0.0, 0.0])
                self.mount = start.x[robot.n_params:robot.n_params + 2].copy()
            else:
                comps = self.components if self.method == "pm-fk" else COMPONENTS
                data = MethodData(qm=qm, channels={"orientation": np.array(
                    [r["orientation"] for r in records])}, components=comps)
                start = robust_start_detail(robot, data, robot.nominal, comps)
        except CalibrationError as e:
            raise WristStopped(f"the wrist's start model cannot be fitted to the {len(records)} "
                               f"poses recorded ({e}); stopped before driving further: "
                               + ADVICE) from e
        rms = max(v for k, v in start.result.residual_rms.items() if not k.startswith("q"))
        if not np.isfinite(rms) or math.degrees(rms) > FIT_RMS_DEG:
            raise WristStopped(f"the wrist's start model does not explain the {len(records)} "
                               f"poses recorded (reading residual RMS {math.degrees(rms):.2f} "
                               f"deg, more than {FIT_RMS_DEG:g}); stopped before driving "
                               "further: " + ADVICE)
        self.xi = start.x[:robot.n_params].copy()
        return start.X

    def next_round(self, records, first_index: int, last_qm, fit_done: int, val_done: int):
        """The next round after every pose of the last one is recorded or dropped:
        ``(poses, wrist record)``, or None when the final round is done."""
        if self.final and not self.replan:
            return None
        # (a round all of whose poses faulted is no progress: it counts as a trip below)
        if self.rounds > 0 and len(records) <= self._recorded and not self.replan:
            self.tripped()        # nothing recorded in the last round (faults): no progress
        self._recorded = len(records)
        fits = [r for r in records if r.get("use", "fit") == "fit"]
        if len(fits) < MIN_FIT_POSES:
            raise WristStopped(f"only {len(fits)} poses near home could be recorded; the "
                               f"wrist's start model needs {MIN_FIT_POSES}. Stopped: " + ADVICE)
        if self.trips >= MAX_TRIPS:
            raise WristStopped(f"the wrist's model failed to predict the measured orientation "
                               f"{self.trips} times in a row (tolerance {TOLERANCE_DEG:g} deg); "
                               "stopped before driving further: " + ADVICE)
        X = self.fit(records)
        heading = self.home_heading()
        grow = 1.0 + (GROW - 1.0) / 2 ** self.trips
        box = min(BOX_DEG, grow * reach_deg(X - [0.0, 0.0, heading]))
        final = box >= BOX_DEG
        rng = np.random.default_rng(self.request.seed + 1 + self.rounds)
        req = self.request
        count = req.count or int(np.ceil(req.margin * minimum_count(
            self.method, self.components if self.method == "pm-fk" else None)))
        if final:
            n_fit = max(count - fit_done, ROUND_COUNT)   # the outer box gets poses of its own
            n_val = max((req.validation if req.validation is not None
                         else max(3, count // 5)) - val_done, 0)
        else:
            n_fit, n_val = ROUND_COUNT, 0
        bounds = np.radians(box) * np.array([[-1.0, 1.0]] * 3)
        bounds[2] += heading
        pool = n_fit + n_val if req.design == "random" else POOL_FACTOR * (n_fit + n_val)
        try:
            plan = planning.sample_poses(self.robot, self.xi, bounds, pool, rng,
                                         accept=self._accept(self.xi))
        except CalibrationError as e:
            raise WristStopped(f"the wrist's current model cannot plan the +-{box:.1f} deg box "
                               f"inside its envelope ({e}): " + ADVICE) from e
        targets, qm, design = plan.targets, plan.qm, None
        if req.design != "random":
            measured = [r["qm"] for r in fits]
            fit_idx, design = choose(
                self.method, self.robot, self.xi, qm, n_fit, measured=measured,
                design=req.design, rng=rng, mount=self.mount,
                components=self.components if self.method == "pm-fk" else None,
                target=req.target if final else None, heldout_qm=qm[:50])
            rest = np.setdiff1d(np.arange(len(qm)), fit_idx)
            keep = np.r_[fit_idx, rng.choice(rest, size=n_val, replace=False)].astype(int)
            targets, qm = targets[keep], qm[keep]
            n_val_idx = np.arange(len(fit_idx), len(keep))
        poses = _finish(self.robot, targets, qm, n_val, rng, last_qm, first_index,
                        self.rounds, validation=None if design is None else n_val_idx)
        rec = {"round": self.rounds, "box_deg": round(box, 3), "final": final,
               "model": self.xi.tolist(), "mount": self.mount.tolist(),
               "reach_deg": round(reach_deg(X - [0.0, 0.0, heading]), 3)}
        if self.method == "pm-tilt":
            rec["home_heading_deg"] = round(math.degrees(heading), 4)
        if design is not None:
            rec["design"] = design.as_record()
        self.rounds += 1
        self.final, self.replan = final, False
        return poses, rec

    def home_heading(self) -> float:
        """pm-tilt: the current model's heading (gamma, rad) at the home actuators, less
        the home's (taken as read, its gamma a guess), else 0. The inclinometer does not
        see the heading, and a model fitted near home gets it wrong by up to ~12 deg
        (the truth's shape fixes it only weakly) while its changes from home are right
        within ~2 deg: pm-tilt's box is centred on the home's heading, and its reach
        measured from there, so that the wrist's true heading stays in the box."""
        if self.method != "pm-tilt" or self.home is None or self.xi is None:
            return 0.0
        home_qm, home_X = self.home
        X = self.predicted(home_qm, np.asarray(home_X, dtype=float))
        return 0.0 if X is None else float(X[2] - np.asarray(home_X, dtype=float)[2])

    # -- while executing ------------------------------------------------------------------------
    def predicted(self, qm, guess) -> np.ndarray | None:
        """Orientation ``(3,)`` the current model gives for ``qm`` (None: it cannot assemble)."""
        try:
            return self.robot.fk(np.atleast_2d(qm), self.xi, guess=guess)[0]
        except CalibrationError:
            return None

    def watch(self, pose: PlannedPose, record: dict) -> str | None:
        """None if the measured orientation of ``record`` is where the current model puts
        it (within :data:`TOLERANCE_DEG`), else what is wrong (the pose must not be
        recorded). The scout round, which has no model yet, is held to the box instead."""
        meas, names = self._measured(record)
        tol = math.radians(TOLERANCE_DEG)
        if self.xi is None or pose.round == 0:
            worst = float(np.max(np.abs(meas)))
            if worst <= math.radians(BOX_DEG) + tol:
                return None
            return (f"pose {pose.index}: measured {math.degrees(worst):.1f} deg, outside the "
                    f"+-{BOX_DEG:g} deg box by more than {TOLERANCE_DEG:g} deg")
        X = self.predicted(record["qm"], np.asarray(pose.target, dtype=float))
        if X is None:
            return (f"pose {pose.index}: the current model cannot assemble at the actuator "
                    f"values reached {np.round(record['qm'], 1).tolist()}")
        pred = self._as_reading(X)
        dev = np.abs((meas - pred + np.pi) % (2 * np.pi) - np.pi)
        if float(dev.max()) <= tol:
            self.trips = 0 if pose.round >= 1 else self.trips
            return None
        j = int(np.argmax(dev))
        return (f"pose {pose.index}: measured {names[j]} {math.degrees(meas[j]):.2f} deg, the "
                f"model predicts {math.degrees(pred[j]):.2f} deg ({math.degrees(dev[j]):.2f} > "
                f"{TOLERANCE_DEG:g} deg)")

    def tripped(self) -> None:
        self.trips += 1
        self.replan = True

    def _measured(self, record):
        if self.method == "pm-tilt":
            return np.asarray(record["tilt"], dtype=float), ("roll", "pitch")
        comps = self.components if self.method == "pm-fk" else COMPONENTS
        return np.asarray(record["orientation"], dtype=float), comps

    def _as_reading(self, X) -> np.ndarray:
        if self.method == "pm-tilt":
            return np.array(gravity_tilt(rot_xyz(X)[0], self.mount))
        comps = self.components if self.method == "pm-fk" else COMPONENTS
        return np.asarray(X)[[COMPONENTS.index(c) for c in comps]]
