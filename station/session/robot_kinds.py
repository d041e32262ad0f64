"""What differs between the robots a session calibrates, one class each.

* :class:`ArmKind`, the built-in AGEBOT arm (agebot-sm): its reference point, the
  distance methods planned in rounds and watched (:class:`station.planning.arm_rounds.
  ArmRounds`) or in one shot, and guided touching;
* :class:`WristKind`, the built-in AGEBOT wrist (agebot-pm): no reference, a start step
  with a test move, a box grown round by round (:class:`station.planning.wrist_plan.
  WristPlanner`) whose watch drops a round the model missed, orientation readings;
* :class:`SerialKind`, a robot file's or URDF robot's arm: its reference and plan from the
  robot's own model (:mod:`station.planning.serial_plan`), its tool inclinometer's roll and
  pitch, and a URDF of the calibration beside the parameter file.

The session (:class:`station.session.session.Session`) holds one (``session.kind``,
:func:`station.session.kinds.robot_kind`) and asks it; a new robot kind is a class here
(or beside: :class:`station.session.marker_kind.MarkersKind`, a URDF robot measured by a
point instrument).
"""
from __future__ import annotations

import numpy as np

from calibration.errors import ConfigError, StationError
from calibration.robots.agebot_pm import euler_from_ypr
from station.fitting.pose_count import minimum_count
from station.fitting.start_values import ROUND_METHODS
from station.planning import arm_plan, serial_plan
from station.planning.arm_rounds import SCOUT_SCALE, ArmRounds
from station.planning.envelope import within_limits
from station.planning.wrist_plan import WristPlanner
from station.recording import resume
from station.recording.planned_pose import PlannedPose
from station.session import plausibility

COMPONENTS = ("alpha", "beta", "gamma")


class RobotKind:
    """A built-in robot's defaults: the planner's reference pose, eq. 60's pose count, one
    plan of every pose, nothing to watch beyond the envelope's limits."""

    def __init__(self, session):
        self.s = session

    def reference_target(self):
        """``(qm, role, instructions)`` of the reference step (qm None: no reference)."""
        s = self.s
        return arm_plan.reference_pose(s.method, s.nominal, s.config.envelope.qm_range)

    def minimum_count(self) -> int:
        return minimum_count(self.s.method, self.s.components)

    def plan(self) -> list[PlannedPose]:
        """Plan (and record) the poses; a kind in rounds plans its first round."""
        raise NotImplementedError

    def plan_text(self, poses, n_val: int, unit: str, how: str, box_scale) -> str:
        """What the ``plan`` event says of ``poses`` (``n_val`` of them held out)."""
        return (f"planned {len(poses)} poses ({n_val} held out for validation; "
                f"eq. 60 minimum {self.s.minimum_count} {unit}{how})")

    @property
    def rounds(self):
        """The arm's rounds (:class:`ArmRounds`), else None."""
        return None

    def rounds_complete(self) -> bool:
        return True

    def next_round(self) -> bool:
        """Plan the next round (recorded); False when there is none."""
        return False

    def predictor(self):
        """What the sensors should read at ``qm`` while a move is watched (None: not
        watched)."""
        return None

    def after_envelope_stop(self, pose: PlannedPose) -> None:
        """The envelope stopped the move to ``pose`` (only where :meth:`predictor` watches)."""

    def watch(self, pose: PlannedPose, rec: dict) -> bool:
        """False where a measured pose must not be recorded (its round re-planned)."""
        return True

    def stage(self, pose: PlannedPose):
        """``(stage, done, total)`` of the progress where poses are counted per round."""
        return None

    def restore(self, events: list[dict]) -> None:
        """A resumed session: what the kind learns from the trace's events."""

    def reading_record(self, m: dict) -> dict:
        """The pose record's readings from a snapshot's means ``m``."""
        return {}

    #: a URDF of the calibration is written beside the parameter file
    urdf = False

    def envelope(self, env):
        """The envelope a move is watched in (the config's)."""
        return env

    def header(self) -> dict:
        """What the kind adds to the trace's header (sm-markers: the points' count)."""
        return {}

    def export(self, doc: dict) -> None:
        """What the kind adds to the parameter file ``doc`` before it is written."""


class ArmKind(RobotKind):
    """The built-in AGEBOT arm (agebot-sm)."""

    def __init__(self, session):
        super().__init__(session)
        self._rounds: ArmRounds | None = None

    @property
    def rounds(self) -> ArmRounds | None:
        """The arm's round plan and envelope model (distance methods, with
        ``PlanRequest.grow`` or resuming such a session), else None."""
        s = self.s
        plans = [e for e in s.events if e.get("kind") == "plan"]
        grow = (any("box_scale" in e for e in plans) if plans       # a resumed one goes on
                else s.request.grow)                                 # as it was planned
        if self._rounds is None and grow and s.method in ROUND_METHODS:
            self._rounds = ArmRounds(s)
        return self._rounds

    def plan(self) -> list[PlannedPose]:
        s = self.s
        if self.rounds is not None:
            poses = self.rounds.first_plan()
            s._set_plan(poses, replace=True, box_scale=SCOUT_SCALE)
            return poses
        start = s.reference_qm
        if start is None and s.rig is not None and all(d.is_open for d in s.rig.devices):
            start = s.qm()
        designs: list = []
        poses = arm_plan.plan_sm(s.method, s.nominal, start, s.request, plane=s.plane,
                                 accept=within_limits(s.config.envelope), design_out=designs)
        if designs:
            s._set_plan(poses, replace=True, design=designs[0])
        else:
            s._set_plan(poses, replace=True, box_scale=None)
        return poses

    def plan_text(self, poses, n_val: int, unit: str, how: str, box_scale) -> str:
        if box_scale is None:
            return super().plan_text(poses, n_val, unit, how, box_scale)
        s = self.s                 # the arm's rounds: this round, then the whole
        rnd = poses[0].round if poses else 0
        fit_all, held_all = self.rounds.fit_total(), self.rounds.totals()[1]
        return (("scout round" if rnd == 0 else f"round {rnd}") + f": planned {len(poses)} "
                f"poses ({n_val} held out for validation), {len(s.plan_poses)} planned "
                f"so far; the rounds plan {fit_all} to fit + {held_all} held out in all "
                f"(eq. 60 minimum {s.minimum_count} {unit} to fit)")

    def rounds_complete(self) -> bool:
        return self.rounds.planned_last() if self.rounds is not None else True

    def next_round(self) -> bool:
        return self.rounds.next_round() if self.rounds is not None else False

    def predictor(self):
        return self.rounds.predictor() if self.rounds is not None else None

    def after_envelope_stop(self, pose: PlannedPose) -> None:
        """The envelope stopped the move to ``pose``: re-plan the rest of its round."""
        self.rounds.replan_after_stop(pose.round, self.rounds.scale_of(pose))

    def reading_record(self, m: dict) -> dict:
        method, rec = self.s.method, {}
        if method in ("sm-distance", "sm-distance-tilt"):
            rec["distance"] = m["distance"]
        if method == "sm-distance-tilt":
            rec["tilt"] = m["tilt"]
        elif method == "sm-distance" and "tilt" in m:
            rec["tilt"] = m["tilt"]    # beside: the rounds' watch learns from it (not fitted)
        return rec


class WristKind(RobotKind):
    """The built-in AGEBOT wrist (agebot-pm): its growing box (station/planning/wrist_plan.py)."""

    def __init__(self, session):
        super().__init__(session)
        s = session
        self.planner = WristPlanner(s.method, s.request, s.components, s.config.envelope.qm_range)

    def restore(self, events: list[dict]) -> None:
        self.planner.components = self.s.components or self.planner.components
        self.planner.restore(events)

    def orientation_now(self) -> np.ndarray:
        """The platform's orientation read now (the inclinometer's roll, pitch, yaw)."""
        r = self.s._rig().read()
        if "yaw" in r:
            return euler_from_ypr(r["roll"], r["pitch"], r["yaw"])
        return np.array([r.get("roll", 0.0), r.get("pitch", 0.0), 0.0])

    def plan(self) -> list[PlannedPose]:
        """The scout round from where the wrist stands (its home), after the start step's
        test move (:func:`station.session.plausibility.check_wrist`)."""
        s = self.s
        rig, home = s._rig(), None

        def start_step(attempt: int):
            nonlocal home
            if home is None:        # where the wrist stands: its start (home) pose
                home = [float(v) for v in rig.qm()]
            elif rig.can_move:      # back there after a fault (a test move's)
                rig.move_to(home)
            found = plausibility.check_wrist(s)      # a flipped sign stops here
            return found, np.array(rig.qm()), self.orientation_now()

        found, home_qm, home_X = s._reference_retried("the wrist's start step", start_step)
        if found:
            s._ensure_trace()
            s._event("info", found)
        self.planner.request = s.request    # the operator may have changed count, seed
        poses, wrist = self.planner.scout(home_qm, home_X)
        s._set_plan(poses, replace=True, wrist=wrist)
        return poses

    def plan_text(self, poses, n_val: int, unit: str, how: str, box_scale) -> str:
        s = self.s
        rnd = poses[0].round if poses else 0
        if rnd == 0:
            return (f"scout round: planned {len(poses)} poses near home; the wrist's start "
                    "model fitted to their readings plans the next rounds, each in a wider box "
                    f"up to the report's (eq. 60 minimum {s.minimum_count} {unit} in all)")
        before = len(s.plan_poses) - len(poses)
        return (f"round {rnd}: planned {len(poses)} poses ({n_val} held out for validation) "
                f"after the {before} of the earlier rounds, {len(s.plan_poses)} in all so "
                f"far (eq. 60 minimum {s.minimum_count} {unit})")

    def rounds_complete(self) -> bool:
        return self.planner.final and not self.planner.replan

    def next_round(self) -> bool:
        """After each round, refit the start model to every recorded pose and plan the
        next, wider round (:class:`station.planning.wrist_plan.WristPlanner`); raises
        :class:`station.planning.wrist_plan.WristStopped` (recorded as an event) where it
        cannot."""
        s = self.s
        if self.rounds_complete():
            return False
        records = sorted(s.measured.values(), key=lambda r: r["index"])
        s._event("info", f"fitting the wrist's start model to {len(records)} poses")
        fit_done = sum(r.get("use", "fit") == "fit" for r in records)
        nxt = max(p.index for p in s.plan_poses) + 1
        last = records[-1]["qm"] if records else None
        try:
            out = self.planner.next_round(records, nxt, last, fit_done, len(records) - fit_done)
        except StationError as e:
            s._event("stop", str(e))
            raise
        if out is None:
            return False
        poses, wrist = out
        s._event("info", f"wrist round {wrist['round']}: box +-{wrist['box_deg']:.1f} deg "
                 f"(measured region {wrist['reach_deg']:.1f} deg)")
        s._set_plan(poses, replace=False, wrist=wrist)
        return True

    def watch(self, pose: PlannedPose, rec: dict) -> bool:
        """True if the measured orientation is where the model predicts; else the pose and
        the rest of its round are dropped and the next round re-planned."""
        s = self.s
        problem = self.planner.watch(pose, rec)
        if problem is None:
            return True
        self.planner.tripped()
        s._event("envelope", f"{problem}: not recorded; the rest of round {pose.round} is "
                 "dropped and re-planned from the poses recorded")
        s._skip(pose, f"pose {pose.index} not recorded (outside the model's tolerance)",
                resume.DROPPED)
        for p in s.pending:
            if p.round == pose.round:
                s._skip(p, f"pose {p.index} dropped: round {pose.round} is re-planned",
                        resume.DROPPED)
        return False

    def stage(self, pose: PlannedPose):
        s = self.s
        same = [q.index for q in s.plan_poses if q.round == pose.round]
        done = sum(i in s.measured or i in s.skipped for i in same)
        return ("scout" if pose.round == 0 else f"round {pose.round}"), done, len(same)

    def reading_record(self, m: dict) -> dict:
        s, rec = self.s, {}
        if s.method == "pm-tilt":
            rec["tilt"] = [m["roll"], m["pitch"]]
        if s.method in ("pm-ik", "pm-fk"):
            if "yaw" not in m:
                raise ConfigError("pm-ik/pm-fk need the sensor's yaw: map roll, pitch and yaw in "
                                  "[inclinometer.axes] (or use pm-tilt, which needs only roll "
                                  "and pitch)", source=s.config.source, key="inclinometer.axes")
            X = euler_from_ypr(m["roll"], m["pitch"], m["yaw"])
            comps = s.components if s.method == "pm-fk" else COMPONENTS
            rec["orientation"] = [float(X[COMPONENTS.index(c)]) for c in comps]
        return rec


class SerialKind(RobotKind):
    """A robot file's or URDF robot's arm (station/planning/serial_plan.py plans it)."""

    def __init__(self, session):
        super().__init__(session)
        self._min_count: int | None = None

    @property
    def tilt_range(self):
        """sm-distance-tilt: ``(roll, pitch, mount)`` of the tool inclinometer (its ranges in
        rad from the station config, None where not stated; its mounting's start values)
        for planning (:func:`station.planning.serial_plan.readable`); None where no range
        is stated."""
        s = self.s
        ranges = plausibility.sensor_ranges(s.config)
        if s.method != "sm-distance-tilt" or not ranges:
            return None
        return (ranges.get("roll"), ranges.get("pitch"),
                (s.extra.get("mount_x", 0.0), s.extra.get("mount_y", 0.0)))

    def reference_target(self):
        s = self.s
        return (serial_plan.reference_pose(s.robot, s.nominal, s.config.envelope.qm_range,
                                           tilt_range=self.tilt_range),
                s.info.reference, serial_plan.REFERENCE_TEXT)

    def minimum_count(self) -> int:
        """Eq. 60 over what the method identifies on this robot (from the reference)."""
        if self._min_count is None:
            s = self.s
            ref = s.reference_qm if s.reference_qm is not None else self.reference_target()[0]
            self._min_count = serial_plan.minimum_count(s.method, s.robot, s.nominal, ref)
        return self._min_count

    def plan(self) -> list[PlannedPose]:
        s = self.s
        targets, qm, use, design = serial_plan.plan(
            s.method, s.robot, s.nominal, s.reference_qm, s.request,
            qm_range=s.config.envelope.qm_range, tilt_range=self.tilt_range)
        poses = [PlannedPose(i, tuple(map(float, q)), tuple(map(float, X)), u)
                 for i, (q, X, u) in enumerate(zip(qm, targets, use))]
        s._set_plan(poses, replace=True, design=design)
        return poses

    def reading_record(self, m: dict) -> dict:
        method, rec = self.s.method, {}
        if method in ("sm-distance", "sm-distance-tilt"):
            rec["distance"] = m["distance"]
        if method == "sm-distance-tilt":     # the tool inclinometer's two axes
            rec["tilt"] = [m["roll"], m["pitch"]]
        return rec

    urdf = True      # calibrated.urdf beside the parameter file (station/outputs/export.py)

    def export(self, doc: dict) -> None:
        doc["robot_file"] = dict(self.s.config.spec.source)   # the calibration keeps it
