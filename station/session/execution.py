"""The session's execution loop: move to each planned pose, (touch,) snapshot, record.

Every pose is moved to inside the envelope (:mod:`station.planning.envelope`: the
config's actuator limits, and the live watch where the robot kind predicts the readings),
measured (averaged and checked by the rig) and appended to the trace with an fsync; a
pair of touched poses is written whole. A device fault goes to the retry policy
(:mod:`station.session.retries`). A kind that plans in rounds plans the next round when
one is measured. :meth:`ExecutionLoop.pause`, :meth:`ExecutionLoop.resume` and
:meth:`ExecutionLoop.abort` come from another thread (the wizard's).
"""
from __future__ import annotations

import math

import dataclasses
import time
from dataclasses import dataclass, field

import numpy as np

from calibration.errors import StationError
from drivers.errors import DeviceError
from station.outputs.units import describe_error
from station.planning.envelope import EnvelopeStop, limit_violation, watched_move
from station.recording import resume
from station.recording.planned_pose import PlannedPose
from station.session import device_loss, plausibility


class SessionAborted(StationError):
    """The operator (or the fault policy) aborted; the trace is intact and resumable."""


class TouchFailed(StationError):
    """The operator could not bring the tool into contact at this pose: skip it."""


@dataclass(frozen=True)
class Progress:
    """What the session is doing: pose ``done`` of ``total`` (planned, incl. held-out),
    the pose being measured and the latest readings (channel -> value). The wrist
    measures in rounds (a scout round near home, then wider ones): ``stage`` is then
    ``"scout"`` or ``"round N"`` and ``stage_done`` of ``stage_total`` count within
    the round (:meth:`label`)."""

    done: int
    total: int
    pose: PlannedPose | None
    readings: dict = field(default_factory=dict)
    message: str = ""
    stage: str = ""
    stage_done: int = 0
    stage_total: int = 0

    def label(self, current: bool = False) -> str:
        """``"pose 5 of 79"``, ``"scout pose 3 of 12"``, ``"round 2: pose 2 of 4"``;
        ``current``: the pose being measured (one more than done)."""
        done, total = ((self.stage_done, self.stage_total) if self.stage
                       else (self.done, self.total))
        text = f"pose {done + (1 if current else 0)} of {total}"
        if self.stage == "scout":
            return "scout " + text
        return f"{self.stage}: {text}" if self.stage else text


class ExecutionLoop:
    """The execution loop of a :class:`~station.session.session.Session` (a part of it:
    reads ``plan_poses``, ``pending``, ``kind``, ``config``, ``fault_policy``, ``touch``;
    writes ``measured``, ``skipped``, the trace)."""

    def pause(self) -> None:
        self._pause.set()
        self._notify("state", "paused")

    def resume(self) -> None:
        self._pause.clear()
        self._notify("state", "measuring")

    def abort(self) -> None:
        self._abort.set()
        self._pause.clear()

    @property
    def paused(self) -> bool:
        return self._pause.is_set()

    def check_abort(self) -> None:
        """For a ``touch`` callback between jogs: raise SessionAborted if abort was asked."""
        if self._abort.is_set():
            raise SessionAborted("aborted by the operator while touching")

    def execute(self) -> int:
        """Measure every pending pose (then, for the wrist, plan and measure the main
        round). Returns the number of poses recorded; raises SessionAborted."""
        self._abort.clear()
        recorded = 0
        if self.pending:
            self._require_touch()
        if self.redo().rezero:       # distances against a lost zero would be wrong
            self.rezero_at_reference()
        self._notify("state", "measuring")
        while True:
            for pose in self.pending:
                if pose.index in self.skipped:      # its pair partner was skipped meanwhile
                    continue
                self._wait_if_paused()
                if self._measure(pose):
                    recorded += 1
            if self.pending:      # re-planned meanwhile (an envelope stop)
                continue
            if not self._plan_next_round():
                break
        if not self.finished:     # what the gate flags, measured again while the robot is here
            recorded += self.confirm_readings()
        self._notify("state", "measured")
        return recorded

    def _wait_if_paused(self) -> None:
        """Before the next pose: wait while paused; SessionAborted where abort was asked."""
        while self._pause.is_set() and not self._abort.is_set():
            time.sleep(0.05)
        if self._abort.is_set():
            self._event("abort", "aborted by the operator")
            raise SessionAborted("aborted; the trace is intact, resume to continue")

    def _progress(self, pose: PlannedPose, readings=None, message: str = "") -> Progress:
        """Progress at ``pose``; the wrist's counts are per round (scout, main)."""
        p = Progress(self._done, len(self.plan_poses), pose, dict(readings or {}), message)
        stage = self.kind.stage(pose)
        if stage is not None:
            p = dataclasses.replace(p, stage=stage[0], stage_done=stage[1],
                                    stage_total=stage[2])
        return p

    @property
    def inclinometer_channels(self) -> tuple[str, ...]:
        """The inclinometer channels this session's method fits."""
        if self.serial:
            return ("roll", "pitch") if self.method == "sm-distance-tilt" else ()
        return plausibility.INCLINOMETER_AXES.get(self.method, ())

    def _measure(self, pose: PlannedPose, remeasure_of: int | None = None) -> bool:
        """Move to ``pose``, measure it and append its record; False where it was not
        recorded (skipped, or dropped by the kind's watch). ``remeasure_of``: the index
        of the reading of ``pose`` this one measures again (:mod:`station.session.confirmation`;
        the gate judges it, not the kind's watch)."""
        rig = self._rig()
        attempt = 0
        while True:
            self._notify("progress", self._progress(pose, message=f"moving to pose {pose.index}"))
            try:
                closed = device_loss.not_connected(rig)     # a reconnection that failed
                if closed is not None:
                    raise closed
                if not self._move(pose):
                    return False
                if self.touching:
                    self._touch(pose)
                snap = rig.snapshot(on_retake=self._settling(f"pose {pose.index}",
                                                              plan_index=pose.index))
                beyond = plausibility.range_problems(
                    self.config, {k: snap.mean.get(k) for k in self.inclinometer_channels},
                    f"at pose {pose.index}")
                if beyond:       # the sensor cannot read there: nothing to record
                    self._skip(pose, f"pose {pose.index} not recorded: " + "; ".join(beyond),
                               resume.DROPPED)
                    return False
                rec = self._pose_record(pose, snap)
                if remeasure_of is not None:
                    rec["remeasure_of"] = remeasure_of
                elif not self.kind.watch(pose, rec):
                    return False
                break
            except TouchFailed as e:
                self._skip(pose, f"pose {pose.index} skipped: no contact ({e})",
                           resume.NO_CONTACT)
                return False
            except SessionAborted:
                self._event("abort", f"aborted at pose {pose.index} while touching")
                raise
            except DeviceError as e:
                self._event("fault", f"pose {pose.index}, attempt {attempt + 1}: "
                            f"{describe_error(e, self.units)}",
                            plan_index=pose.index, device=e.device)
                action = self.fault_policy(pose, e, attempt)
                if action == "reconnect":     # the devices are gone: connected anew, then on
                    self._event("abort", f"stopped at pose {pose.index} to connect the "
                                "devices anew (Retry after they were lost)")
                    raise SessionAborted(f"stopped to connect the devices anew: {e}") from e
                if action == "abort":
                    self._event("abort", f"aborted at pose {pose.index} after a fault")
                    raise SessionAborted(f"aborted after a fault: {e}") from e
                if action == "skip":
                    self._raise_if_lost(rig, e)          # the device, or only this pose?
                    self._skip(pose, f"pose {pose.index} skipped", resume.FAULT)
                    return False
                attempt += 1
                self._pause_to_retry(f"pose {pose.index}", attempt, plan_index=pose.index)
        self._next_index += 1
        rest = [p for p in self.group_of(pose) if p.index != pose.index
                and p.index not in self.measured and p.index not in self._held]
        if rest:      # a pair is written whole: a lone pose of a pair is of no use
            self._held[pose.index] = rec
        else:
            w = self._ensure_trace()
            for p in self.group_of(pose):
                if p.index in self._held:
                    w.append(self._held[p.index])
                    self.measured[p.index] = self._held.pop(p.index)
            w.append(rec)
            self.measured[pose.index] = rec
        shown = (dict(snap.mean) if not self.touching else   # touching records qm only
                 {k: v for k, v in snap.mean.items() if k.startswith("qm")})
        self._notify("progress", self._progress(pose, shown, f"pose {pose.index} " + (
            "touched (written with its pair)" if rest else "recorded")))
        return True

    def _move(self, pose: PlannedPose) -> bool:
        """Move to ``pose`` inside the envelope (:mod:`station.planning.envelope`): a pose
        beyond the config's actuator limits is skipped unmoved; the arm's move is watched
        against its current model, and where it departs the arm stops, the pose is
        skipped and the round re-planned. False where the pose was not reached."""
        env = self.kind.envelope(self.config.envelope)
        why = limit_violation(pose.qm, env)
        if why is not None:
            self._skip(pose, f"pose {pose.index} skipped before moving: {why}", resume.DROPPED)
            return False
        predict = self._ranged(self.kind.predictor())
        came_from = self.qm() if predict is not None else None
        try:
            halts = watched_move(self._rig(), pose.qm, predict, env,
                                 self.config.canopen.move_timeout)
        except EnvelopeStop as e:
            self._event("envelope", f"pose {pose.index}: {e}; back to where the move started",
                        plan_index=pose.index, qm=e.qm.tolist(),
                        departed={k: list(v) for k, v in e.departed.items()},
                        readings=e.readings)
            self._skip(pose, f"pose {pose.index} not recorded: the arm was stopped by the "
                       "envelope", resume.DROPPED)
            # back the way it came (the same straight line in actuator space): where the
            # model departs already, every move from there would be stopped at once
            self._rig().move_to(came_from)
            self.kind.after_envelope_stop(pose)
            return False
        if halts:
            self._event("info", f"pose {pose.index}: the move was halted {halts} times where "
                        "the readings departed while moving but agreed with the model at rest "
                        "(a sensor later than the config's [envelope] latency); it went on")
        return True

    def _ranged(self, predict):
        """``predict`` with every channel beyond the sensor's range (config
        ``range_rad``) predicted as NaN: not compared by the live watch, the sensor
        cannot read there."""
        ranges = plausibility.sensor_ranges(self.config)
        if predict is None or not ranges:
            return predict

        def wrapped(qm):
            out = dict(predict(qm))
            for ch, r in ranges.items():
                if ch in out:
                    v = np.asarray(out[ch], dtype=float)
                    out[ch] = np.where(np.abs(v) > r, np.nan, v) if v.ndim else (
                        float("nan") if abs(float(v)) > r else float(v))
            return out
        return wrapped

    def _require_touch(self) -> None:
        if self.touching and self.touch is None:
            raise StationError(f"{self.method} is measured by guided touching: the session "
                               "needs a touch callback (the operator who brings the tool into "
                               "contact; app.py run --simulate has a simulated one)")

    def _touch(self, pose: PlannedPose) -> None:
        self._notify("progress", self._progress(pose, message=f"touching at pose {pose.index}"))
        self.touch(self, pose)

    def _skip(self, pose: PlannedPose, message: str, reason: str) -> None:
        """Skip ``pose`` (``reason``: :data:`station.recording.resume.FAULT` or
        ``NO_CONTACT``; a fault's poses are measured again on resume); for a pair, also
        its partners not written yet (touched ones are dropped: a pair is written whole)."""
        self.skipped.add(pose.index)
        self._event("skip", message, plan_index=pose.index, reason=reason)
        for p in self.group_of(pose):
            if p.index not in self.measured and p.index not in self.skipped:
                self._held.pop(p.index, None)
                self.skipped.add(p.index)
                self._event("skip", f"pose {p.index} skipped with its pair partner {pose.index}",
                            plan_index=p.index, reason=reason)

    def _pose_record(self, pose: PlannedPose, snap) -> dict:
        m = snap.mean
        n = self.robot.n_actuators
        qm = [m[f"qm{i + 1}"] for i in range(n)]
        rec = {"record": "pose", "index": self._next_index, "plan_index": pose.index,
               "qm": qm, "target": list(pose.target), "use": pose.use, "t": snap.t_start,
               "samples": snap.samples,
               "std": {k: (v if math.isfinite(v) else None) for k, v in snap.std.items()}}
        if pose.group is not None:
            rec["group"] = int(pose.group)
        rec.update(self.kind.reading_record(m))
        return rec
