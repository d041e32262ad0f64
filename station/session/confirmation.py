"""The session measures again before it refuses: what the gate flags is confirmed at the robot.

At the end of measuring, while the robot is still in front of the station, the trace is
calibrated as the calibration step will calibrate it (:func:`station.fitting.batch.calibrate`,
with the fit-quality gate), and every reading the gate flags (:func:`flagged`: a reading left
out as an outlier, a held-out reading beyond its prediction's std) is measured again:

* a ``remeasure`` event names the pose and why, before the arm moves;
* the arm approaches the pose again at :data:`REAPPROACH` of its profile velocity (from the
  pose measured before it, where the arm is at that pose already), watched as every move;
* the new reading is appended as a pose record with ``remeasure_of`` (the reading it
  measures again); the earlier one stays in the trace and the calibration takes a pose's
  newest reading (:attr:`station.recording.trace.Trace.remeasured`).

Then the trace is checked again, until the gate flags nothing new. A pose is measured again
at most :data:`MAX_REMEASURE` times (an attempt that failed, a ``remeasure-failed`` event,
counts too); a reading still flagged after that is what the robot confirms: a
``confirmed`` event says so and the gate's verdict on it stands. The counts come from the
trace, so a resumed session measures again exactly as far as the uninterrupted one would.
"""
from __future__ import annotations

import warnings

import numpy as np

from calibration.errors import CalibrationError
from drivers.errors import DeviceError
from station.fitting.batch import calibrate
from station.fitting.verdict import FitQualityError, describe

#: times one pose is measured again at most
MAX_REMEASURE = 2
#: the re-approach's share of the drives' profile velocity
REAPPROACH = 0.5
#: actuator units: the arm is at a pose already where every actuator is this close
AT_POSE = 1e-6


def flagged(outcome) -> dict[int, str]:
    """The readings the gate flags in ``outcome``
    (:class:`~station.fitting.outcome.BatchOutcome`): pose index -> why, in words. Outliers
    left out (not their pair partners, left out only for company) and held-out readings
    beyond their prediction's std."""
    q = outcome.quality
    out: dict[int, str] = {}
    for o in q.outliers:
        out.setdefault(int(o["pose"]), f"{describe(o)} left out of the fit as an outlier "
                       f"(studentized residual {o['t']:.3g} > {o['threshold']:.3g})")
    for c in q.checks:
        h = c.get("heldout")
        if c["check"] == "validation" and not c["ok"] and h and h.get("pose") is not None:
            where = f" point {h['point']}" if "point" in h else f" {c['channel']}"
            out.setdefault(int(h["pose"]), f"held-out pose {h['pose']}{where} is {h['t']:.3g} "
                           f"times its predicted std off the calibration's prediction "
                           f"(threshold {h['threshold']:.3g})")
    return out


def _checked(trace):
    """The gate's outcome of ``trace`` whether it passed or not; None where there is no fit
    (it does not converge, too few poses). Its warnings are the calibration step's to say."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        try:
            return calibrate(trace)
        except FitQualityError as e:
            return e.outcome
        except CalibrationError:
            return None


class ConfirmStep:
    """The confirmation of flagged readings of a :class:`~station.session.session.Session`
    (a part of it: reads the trace, ``plan_poses``, ``rig``, ``reference_qm``; measures with
    :meth:`~station.session.execution.ExecutionLoop._measure`)."""

    def confirm_readings(self) -> int:
        """Measure again what the gate flags (module docstring), as long as it flags a
        pose not measured again :data:`MAX_REMEASURE` times yet. Returns the number of
        readings measured again. Not where the station cannot move the robot."""
        if self.rig is None or not self.rig.can_move:
            return 0
        again = 0
        while True:
            trace = self.read_own_trace()
            outcome = _checked(trace)
            if outcome is None:
                return again       # no fit to judge the readings by: the calibration says why
            todo = []
            for index, why in sorted(flagged(outcome).items()):
                rec = next(p for p in trace.poses if p["index"] == index)
                pose = self._planned(rec)
                if pose is None:
                    continue
                tries = self._remeasured(trace, pose.index)
                if tries >= MAX_REMEASURE:
                    self._confirmed(trace, rec, why, tries)
                else:
                    todo.append((pose, rec, why))
            if not todo:
                return again
            for pose, rec, why in todo:
                self._wait_if_paused()
                if self._measure_again(pose, rec, why):
                    again += 1

    def _planned(self, rec: dict):
        """The planned pose of a pose record; None where it has none (nothing to go back
        to) or it is one of a pair (sm-self-redundancy: the second pose touches the mark
        the first one found, so one alone cannot be measured again)."""
        i = rec.get("plan_index")
        pose = next((p for p in self.plan_poses if p.index == i), None)
        return None if pose is None or pose.group is not None else pose

    def _remeasured(self, trace, plan_index: int) -> int:
        """How often the trace measured plan pose ``plan_index`` again: its readings after
        the first, and the attempts that failed."""
        readings = sum(1 for p in trace.poses if p.get("plan_index") == plan_index)
        failed = sum(1 for ev in trace.events if ev.get("kind") == "remeasure-failed"
                     and ev.get("plan_index") == plan_index)
        return max(readings - 1, 0) + failed

    def _confirmed(self, trace, rec: dict, why: str, tries: int) -> None:
        """A ``confirmed`` event for a reading still flagged after the last re-measurement
        (once: a resumed session that finds it in its trace says nothing again)."""
        if any(ev.get("kind") == "confirmed" and ev.get("pose") == rec["index"]
               for ev in trace.events):
            return
        readings = trace.readings_of(rec["index"])
        shown = ", ".join(str(p["index"]) for p in readings)
        self._event("confirmed", f"pose {rec['plan_index']} measured {len(readings)} times "
                    f"(readings {shown}; {tries} attempt(s) again): {why}; the robot confirms "
                    "it, the fit-quality gate judges it", plan_index=rec["plan_index"],
                    pose=rec["index"])

    def _measure_again(self, pose, rec: dict, why: str) -> bool:
        """One re-measurement of ``pose`` whose newest reading is ``rec`` (module
        docstring); False where it was not measured (a ``remeasure-failed`` event)."""
        self._event("remeasure", f"pose {pose.index} measured again ({why}): approached "
                    f"again at {REAPPROACH:.0%} speed", plan_index=pose.index,
                    pose=rec["index"], reason=why)
        rig = self._rig()
        try:
            with rig.slower(REAPPROACH):
                if np.max(np.abs(np.asarray(self.qm()) - np.asarray(pose.qm))) <= AT_POSE:
                    self.move_to(self._away_from(rec))     # a new approach, not a new look
                done = self._measure(pose, remeasure_of=int(rec["index"]))
        except DeviceError as e:
            self._event("fault", f"pose {pose.index} measured again: {e}",
                        plan_index=pose.index, device=e.device)
            done = False
        if not done:
            self.skipped.discard(pose.index)      # measured: its earlier reading stands
            self._event("remeasure-failed", f"pose {pose.index} was not measured again; its "
                        f"reading {rec['index']} stands", plan_index=pose.index,
                        pose=rec["index"])
        return done

    def _away_from(self, rec: dict) -> list[float]:
        """Where to leave a pose from to approach it again: the pose measured before it,
        else the reference, else the pose measured after it."""
        order = sorted(self.measured.values(), key=lambda p: p["index"])
        before = [p for p in order if p["index"] < rec["index"]]
        if before:
            return list(before[-1]["qm"])
        if self.reference_qm is not None:
            return [float(v) for v in self.reference_qm]
        after = [p for p in order if p["index"] > rec["index"]]
        return list(after[0]["qm"]) if after else list(rec["qm"])
