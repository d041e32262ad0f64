"""The session's planning step: which poses to measure, recorded in the trace.

The robot kind plans (:mod:`station.session.robot_kinds`: the arm in rounds or in one
shot, the wrist's growing box, a robot file's serial plan); every plan is a ``plan``
event with its poses, so a resumed session knows its plan (:mod:`station.recording.resume`).
A kind that plans in rounds plans the next one when the last is measured
(:meth:`PlanningStep._plan_next_round`, from the execution loop).
"""
from __future__ import annotations

from calibration.errors import StationError
from station.planning.pose_design import design_text
from station.recording import resume
from station.recording.planned_pose import PlannedPose


class PlanningStep:
    """The planning step of a :class:`~station.session.session.Session` (a part of it:
    reads ``kind``, ``method``, ``measured``, ``skipped``, ``reference_qm``; writes
    ``plan_poses``, ``last_design``)."""

    @property
    def pending(self) -> list[PlannedPose]:
        return resume.pending(self.plan_poses, self.measured, self.skipped, self._held)

    @property
    def _done(self) -> int:
        return len(self.measured) + len(self.skipped) + len(self._held)

    @property
    def minimum_count(self) -> int:
        """Eq. 60's minimum pose count of this session's method on its robot."""
        return self.kind.minimum_count()

    def plan(self) -> list[PlannedPose]:
        """Plan the poses (all of them; for the wrist the scout round, the rest follows
        it automatically in :meth:`execute`). Replaces a plan none of whose poses
        were measured yet."""
        if any(p.index in self.measured for p in self.plan_poses):
            raise StationError("poses of the current plan are recorded already: a new plan "
                               "needs a new session")
        if self.needs_reference and self.reference_qm is None:
            raise StationError("capture the reference first")
        if self.method == "sm-plane" and self.plane is None:
            raise StationError("sm-plane needs the plane as the engineer measured it, in the "
                               "robot's base frame: plane_a, plane_b, plane_c of "
                               "a x + b y + c z + 1 = 0 (1/m) as start values "
                               "(app.py run --nominal plane_a=... --nominal plane_b=... "
                               "--nominal plane_c=...)")
        if self.touching and self.missing_known():
            self._ensure_trace()
            self._event("warning", f"{', '.join(self.missing_known())}: not identifiable by "
                        f"{self.method} and they influence the result; their start values "
                        "(the robot's nominal) must be right, or the other parameters come "
                        "out biased. Give the measured values as start values.")
        return self.kind.plan()

    def set_plan(self, poses: list[PlannedPose]) -> None:
        """Replace the plan (edited by the operator) while none of its poses is measured;
        the new plan is recorded in the trace."""
        if any(p.index in self.measured for p in self.plan_poses):
            raise StationError("poses of the current plan are recorded already: a new plan "
                               "needs a new session")
        if len({p.index for p in poses}) != len(poses):
            raise StationError("planned poses must have distinct indices")
        self._set_plan(list(poses), replace=True)

    @property
    def rounds(self):
        """The arm's round plan and envelope model (:class:`station.planning.arm_rounds.
        ArmRounds`: distance methods, with ``PlanRequest.grow`` or resuming such a
        session), else None."""
        return self.kind.rounds

    def _set_plan(self, poses: list[PlannedPose], replace: bool,
                  box_scale: float | None = None, **extra) -> None:
        if box_scale is not None:                 # the arm's rounds
            extra["box_scale"] = box_scale
            if replace:                           # the session's counts
                extra["totals"] = list(self.rounds.totals())
        if replace:
            self.plan_poses = list(poses)
        else:
            self.plan_poses += poses
        n_val = sum(p.use == "validation" for p in poses)
        self._ensure_trace()
        unit = "pairs" if self.method == "sm-self-redundancy" else "poses"
        how = (f"; each touched from its approach pose ({self.method})" if self.touching else "")
        text = self.kind.plan_text(poses, n_val, unit, how, box_scale)
        design = extra.get("design") or (extra.get("wrist") or {}).get("design")
        if design:
            text += "; " + design_text(design, self.units)
            self.last_design = design
        self._event("plan", text, poses=[p.record() for p in poses], replace=replace, **extra)
        self._notify("state", "planned")

    @property
    def rounds_complete(self) -> bool:
        """False while the wrist's growing box (station/planning/wrist_plan.py) or the arm's
        rounds (station/planning/arm_rounds.py) have rounds to plan."""
        return self.kind.rounds_complete()

    def _plan_next_round(self) -> bool:
        """Plan the next round where the kind plans in rounds (recorded); False when the
        last one is planned."""
        return self.kind.next_round()
