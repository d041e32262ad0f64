"""The station session: reference, IK-planned poses, crash-safe recording,
calibration, validation, export and report. No Qt here: the GUI and the
headless run (``app.py run``) are two faces of this one object.

Workflow (each step may be repeated; the trace records everything)::

    s = Session(config, "sm-distance-tilt", "out/")   # resumes out/trace.jsonl if present
    s.connect()                                        # opens the devices (drivers.rig.Rig)
    s.move_to(s.reference_target().qm); s.capture_reference()
    s.plan()                                           # eq. 60 count, IK, short travel
    s.execute()                                        # move, settle, snapshot, append+fsync
    s.calibrate(); s.validate(); s.export()            # params.json, report.html

Guided touching (sm-plane, sm-self-redundancy; report 7.4, 7.3): the session
drives to each planned approach pose and calls ``touch(session, pose)``, which
brings the tool tip into contact (an operator jogging with :meth:`Session.jog` /
:meth:`Session.move_to` until the tip touches the plane, or the pair's mark) and
returns; the session then snapshots and records ``qm`` (and ``group``). ``touch``
raises :class:`TouchFailed` where the contact cannot be made (the pose is
skipped, with its pair) and :class:`SessionAborted` to stop. Which operator
touches is not the session's business (:mod:`station.simulation.touch_operator` is the
simulated one).

Crash safety: the trace (file-formats.md) is the session's only state. The
plan is recorded as an ``event`` of kind ``plan`` (with its poses), each
measured pose carries ``plan_index``, skipped poses an event of kind ``skip``;
so :class:`Session` on an existing trace continues with the poses not yet
measured, whatever moment the previous process died at; :mod:`station.recording.resume`
decides what it must redo first. The session holds the folder's lock
(:mod:`station.recording.lock`) from its start to :meth:`close`: a second session on the
folder is refused, naming the first one's process.

Threads: :meth:`execute` and :meth:`calibrate` block; a GUI runs them in a
worker thread and talks to them with :meth:`pause`, :meth:`resume`,
:meth:`abort` and the ``observer`` and ``fault_policy`` callbacks, which are
called from that worker thread.
"""
from __future__ import annotations

import dataclasses
import logging
import math
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from calibration.errors import ConfigError, StationError
from calibration.methods import METHODS, extra_params
from calibration.robots import get_robot
from calibration.robots.agebot_pm import euler_from_ypr
from drivers.config import StationConfig
from drivers.errors import DeviceError
from drivers.check import hint_for
from station.planning import arm_plan as planner, serial_plan
from station.recording import resume
from station.session import device_loss, plausibility
from station.planning.arm_rounds import SCOUT_SCALE, ArmRounds
from station.fitting.start_values import ROUND_METHODS
from station.planning.envelope import EnvelopeStop, limit_violation, watched_move, within_limits
from station.fitting.batch import calibrate
from station.fitting.outcome import BatchOutcome
from station.outputs.fit_summary import outcome_document
from station.fitting.verdict import FitQualityError
from station.recording.lock import FolderLock
from station.outputs.params_file import read_params, write_params
from station.planning.request import PlanRequest
from station.recording.planned_pose import PlannedPose
from station.planning.pose_design import design_text
from station.recording.trace import read_trace, utc_now
from station.recording.trace_writer import TraceWriter
from station.outputs.units import describe_error, from_config as units_from_config
from station.fitting.validation import validation_errors
from station.planning.wrist_plan import WristPlanner

log = logging.getLogger("station.session")

TRACE, PARAMS, REPORT = "trace.jsonl", "params.json", "report.html"
URDF = "calibrated.urdf"     # a robot file's session
COMPONENTS = ("alpha", "beta", "gamma")


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


Observer = Callable[[str, object], None]           # (kind, payload): "progress", "event", "state"
FaultPolicy = Callable[[PlannedPose, DeviceError, int], str]   # -> "retry" | "skip" | "abort"
Touch = Callable[["Session", PlannedPose], None]   # brings the tool into contact, then returns


def retry_then_skip(retries: int = 3, window: float = 0.0) -> FaultPolicy:
    """The headless policy: retry a faulty pose ``retries`` times (after pauses of
    0.25, 0.5, 1 s: :func:`station.session.device_loss.backoff`), and for as long as
    ``window`` seconds from its first fault (the station config's
    ``session.retry_window``), then skip it, unless the device itself is gone
    (:func:`station.session.device_loss.probe`: the session stops)."""
    first: dict = {}

    def policy(pose, error, attempt):
        now = time.monotonic()
        if attempt == 0:
            first[pose.index] = now
        within = now - first.setdefault(pose.index, now) < window
        return "retry" if attempt < retries or within else "skip"
    policy.retries = retries      # the reference step's retries (Session.reference_retries)
    policy.window = window        # ... and its window (Session.retry_window)
    return policy


#: retries of the reference step where the fault policy states none (an operator's,
#: asked per pose in the wizard): as many as :func:`retry_then_skip`'s default
REFERENCE_RETRIES = 3


class Session:
    """One calibration session of one robot with one method, recorded in ``out_dir``.

    config:   the station config (endpoints resolved). method: a session method
              (:data:`station.planning.request.SESSION_METHODS`).
    out_dir:  folder of ``trace.jsonl``, ``params.json``, ``report.html``; an existing
              trace there is resumed (its robot and method must match).
    request:  pose count, held-out count, seed (:class:`~station.planning.request.PlanRequest`).
    observer: ``observer(kind, payload)`` for progress, events and state changes.
    fault_policy: what to do when a pose fails (default: retry twice, then skip).
    rig:      devices to use (default: built from ``config`` at :meth:`connect`).
    nominal:  parameter name -> start value over the robot model's nominal (values the
              engineer knows, e.g. a gear ratio from the datasheet), and the method's
              extra parameters (sm-plane: ``plane_a, plane_b, plane_c``, the plane as
              measured); a resumed trace keeps its own. Written into the trace header.
    touch:    guided touching (sm-plane, sm-self-redundancy): ``touch(session, pose)``
              brings the tool into contact from the approach pose (module docstring).
    station:  more for the trace header's ``station`` field (e.g. ``simulator``: its
              truth file and seed).
    accept_poor_fit: export a fit that failed the quality gate (recorded in ``fit.quality``).
    """

    def __init__(self, config: StationConfig, method: str, out_dir, *,
                 request: PlanRequest | None = None, observer: Observer | None = None,
                 fault_policy: FaultPolicy | None = None, rig=None,
                 nominal: dict | None = None, touch: Touch | None = None,
                 station: dict | None = None, accept_poor_fit: bool = False):
        planner.check_method(method)
        mi = METHODS[method]
        robot = get_robot(config.robot_model)     # a built-in or the config's robot file
        if robot.kind != mi.kind:
            raise ConfigError(f"the station is for {config.robot} (a {robot.kind} robot), method "
                              f"{method} needs a {mi.kind} one", source=config.source, key="robot")
        plausibility.check_config(config, method)     # before any motion
        self.config, self.method, self.info = config, method, mi
        self.units = units_from_config(config)         # numbers for people
        self.last_design: dict | None = None               # the last plan's pose design
        self.robot = robot
        self.out = Path(out_dir)
        self.request = request or PlanRequest()
        self.observer = observer
        self.fault_policy = fault_policy or retry_then_skip(
            window=config.session.retry_window)
        # a transient fault of the reference step (or the wrist's start step) is retried
        # this many times, and within this window (s): the policy's own where it states
        # them (headless)
        self.reference_retries = int(getattr(self.fault_policy, "retries", REFERENCE_RETRIES))
        self.retry_window = float(getattr(self.fault_policy, "window", 0.0))
        self.rig = rig
        self.touch = touch
        self.station_record = dict(station or {})   # more for the header's station field
        self.accept_poor_fit = accept_poor_fit
        given = dict(nominal or {})
        self.extra = {k: float(given.pop(k)) for k in extra_params(method, robot) if k in given}
        self.nominal = self.robot.params(given, source="nominal")
        self.known = set(given) | set(self.extra)    # start values the engineer gave
        self.components = tuple(self.request.components) if method == "pm-fk" else None
        self.reference_qm: np.ndarray | None = None
        self.reference_record: dict | None = None
        self.plan_poses: list[PlannedPose] = []
        self.measured: dict[int, dict] = {}        # plan index -> pose record
        self._held: dict[int, dict] = {}           # pair poses touched, written with the pair
        self.skipped: set[int] = set()
        self.remeasure: set[int] = set()           # skipped for a fault before a resume
        self.zeroed = False                        # this process zeroed the draw-wire
        self.events: list[dict] = []
        self.outcome: BatchOutcome | None = None
        self.validation: list[dict] | None = None
        self.exported: dict | None = None
        self._writer: TraceWriter | None = None
        self._next_index = 0
        self._pause = threading.Event()
        self._abort = threading.Event()
        # the wrist's growing box (station/planning/wrist_plan.py)
        self.wrist = (WristPlanner(method, self.request, self.components, config.envelope.qm_range)
                      if self.robot.name == "agebot-pm" else None)
        self._rounds: ArmRounds | None = None   # the arm's rounds (station/planning/arm_rounds.py)
        self.finished = False     # resumed a session that was measured and exported
        self._quiet = False       # events shown, not appended (a finished session)
        from drivers.atomic import check_output_folder   # the wizard's folder as run's

        check_output_folder(self.out, "the session folder", (TRACE, PARAMS, REPORT, URDF),
                            inputs=tuple(p for p in (config.source,) if p))
        self._lock = FolderLock(self.out).acquire()    # one session per folder
        try:
            resume.unstarted(self.trace_path)  # a header cut by a crash: nothing to resume
            self.resumed = self.trace_path.exists()
            if self.resumed:
                self._load()
        except BaseException:
            self._lock.release()
            raise
        if self._lock.stale:
            self._event("info", self._lock.stale_text())

    # -- files ------------------------------------------------------------------------------
    @property
    def trace_path(self) -> Path:
        return self.out / TRACE

    def _load(self) -> None:
        self._writer = TraceWriter.resume(self.trace_path)
        tr = self._writer.trace
        if tr.robot != self.robot.name or tr.method != self.method:
            self._writer.close()
            self._writer = None
            raise ConfigError(f"this trace is a {tr.robot} {tr.method} session, not "
                              f"{self.robot.name} {self.method}: choose another folder",
                              source=str(self.trace_path))
        self.nominal = tr.nominal_vector(self.robot, self.info.extra_params)[:self.robot.n_params]
        nom = tr.header.get("nominal") or {}
        self.extra = {k: float(nom[k]) for k in extra_params(self.method, self.robot)
                      if k in nom}
        self.known = set(nom)
        if tr.header.get("components"):
            self.components = tuple(tr.header["components"])
        if tr.reference is not None:
            self.reference_qm = np.array(tr.reference["qm"], dtype=float)
            self.reference_record = tr.reference
        self.events.extend(tr.events)
        for ev in tr.events:
            if ev.get("kind") == "plan":
                rec = ev.get("design") or (ev.get("wrist") or {}).get("design")
                self.last_design = rec if isinstance(rec, dict) else self.last_design
        done = resume.restore(tr)
        self.plan_poses, self.measured = done.plan, done.measured
        self.skipped, self.remeasure = set(done.skipped), set(done.remeasure)
        self._next_index = done.next_index
        if self.wrist is not None:
            self.wrist.components = self.components or self.wrist.components
            self.wrist.restore(tr.events)
        self.finished = resume.finished(self.trace_path, self.pending,
                                        (self.out / PARAMS, self.out / REPORT))
        if self.finished:      # nothing new: left as it is, no event appended
            return
        self._event("resume", f"resumed: {len(self.measured)} poses recorded, "
                    f"{len(self.pending)} still to measure; to do: {self.redo().describe()}")

    def _ensure_trace(self) -> TraceWriter:
        if self._writer is None:
            self.out.mkdir(parents=True, exist_ok=True)
            header = {"robot": self.robot.name, "method": self.method,
                      **({"robot_file": dict(self.config.spec.source)} if self.serial else {}),
                      "nominal": {**self.robot.as_dict(self.nominal), **self.extra},
                      "station": {"config": self.config.source, "software": "calstation",
                                  "devices": [d.name for d in self.rig.devices] if self.rig
                                  else [], **self.station_record}}
            if self.components:
                header["components"] = list(self.components)
            self._writer = TraceWriter.create(self.trace_path, header)
        return self._writer

    def _event(self, kind: str, message: str, **extra) -> None:
        rec = {"record": "event", "t": utc_now(), "kind": kind, "message": message, **extra}
        if self._writer is not None and not self._quiet:
            self._writer.append(rec)
        self.events.append(rec)
        log.info("%s: %s", kind, message)
        self._notify("event", rec)

    def _notify(self, kind: str, payload) -> None:
        if self.observer is not None:
            try:
                self.observer(kind, payload)
            except Exception:   # a broken display must never lose a measurement
                log.exception("observer failed")

    # -- devices ------------------------------------------------------------------------------
    def connect(self) -> None:
        if self.rig is None:
            from drivers.rig import Rig

            self.rig = Rig(self.config)
        self.rig.open()
        self._notify("state", "connected")

    def close(self) -> None:
        if self.rig is not None:
            self.rig.close()
        if self._writer is not None:
            self._writer.close()
            self._writer = None
        self._lock.release()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def readings(self) -> dict[str, float]:
        """One live reading of every channel."""
        return self._rig().read()

    def move_to(self, qm) -> None:
        """Move to ``qm`` (actuator units); a target beyond the config's actuator limits
        is refused (:class:`~calibration.errors.StationError`) and the robot stays."""
        why = limit_violation(qm, self.config.envelope)
        if why is not None:
            raise StationError(f"not moved: {why} ([envelope] of the station config)")
        self._rig().move_to([float(v) for v in qm])

    def jog(self, axis: int, delta: float) -> None:
        """Move actuator ``axis`` (0-based) by ``delta`` actuator units."""
        qm = self._rig().qm()
        qm[axis] += float(delta)
        self.move_to(qm)

    def qm(self) -> np.ndarray:
        """The actuator values now (one reading)."""
        return np.array(self._rig().qm(), dtype=float)

    def check_abort(self) -> None:
        """For a ``touch`` callback between jogs: raise SessionAborted if abort was asked."""
        if self._abort.is_set():
            raise SessionAborted("aborted by the operator while touching")

    def _rig(self):
        if self.rig is None:
            raise StationError("the devices are not connected: connect first")
        closed = device_loss.not_connected(self.rig)
        if closed is not None:
            raise StationError(f"{closed}: {hint_for(closed.device, self.simulated)}"
                               + ("" if self.simulated else ", then connect again"))
        return self.rig

    # -- reference ------------------------------------------------------------------------------
    @property
    def needs_reference(self) -> bool:
        return self.info.reference is not None

    def reference_target(self):
        """``(qm, role, instructions)`` for the reference step (qm None: no reference)."""
        if self.serial:
            return (serial_plan.reference_pose(self.robot, self.nominal,
                                               self.config.envelope.qm_range,
                                               tilt_range=self.tilt_range),
                    self.info.reference, serial_plan.REFERENCE_TEXT)
        return planner.reference_pose(self.method, self.nominal, self.config.envelope.qm_range)

    def capture_reference(self, qm=None) -> np.ndarray:
        """Record the current pose (``qm`` given: drive there first, the headless run)
        as the reference: zero the draw-wire (the cable is attached here), then measure
        the pose as any other (averaged, checked) and write the reference record. The
        zero is one reading with noise, so the record says ``zero = "reading"`` (the
        method calibrates ``distance_off``) and keeps the averaged reading there as
        ``tare`` (checked again on resume). Before any pose is measured the reference
        may be captured again: the new record (and its zero) replaces the earlier one,
        in the trace as on resume.

        A device fault on the way (the move, the plausibility test move, the zero, a
        reading of the tare) is retried as a pose's is (:meth:`_reference_retried`):
        the arm back where the step started and the whole capture again (zero and
        every reading), so the record never mixes readings from before and after it."""
        if not self.needs_reference:
            raise StationError(f"method {self.method} has no reference step")
        if self.reference_qm is not None and self.measured:
            raise StationError("poses were measured from this reference: a new reference "
                               "needs a new session folder")
        again = self.reference_qm is not None
        rig = self._rig()
        where = None if qm is None else [float(v) for v in qm]
        if where is not None:
            why = limit_violation(where, self.config.envelope)
            if why is not None:
                raise StationError(f"not moved: {why} ([envelope] of the station config)")

        def capture(attempt: int):
            nonlocal where
            if where is None:          # here: where the operator left the arm
                where = [float(v) for v in rig.qm()]
            elif (attempt or qm is not None) and rig.can_move:
                rig.move_to(where)     # there, or back after a fault (a test move's)
            found = plausibility.check_reference(self)   # a mis-configured device stops here
            if rig.drawwire is not None:
                rig.zero_drawwire()
            return found, rig.snapshot()

        found, snap = self._reference_retried("the reference step", capture)
        qm = np.array([snap.mean[f"qm{i + 1}"] for i in range(self.robot.n_actuators)])
        rec = {"record": "reference", "role": self.info.reference, "qm": qm.tolist(),
               "t": utc_now(), "samples": snap.samples}
        if rig.drawwire is not None:
            rec["zero"] = "reading"
            rec["tare"] = _tare(snap)
        if "tilt" in snap.mean:
            rec["tilt"] = float(snap.mean["tilt"])
        w = self._ensure_trace()
        w.append(rec)
        self.reference_qm = qm
        self.reference_record = rec
        self.zeroed = rig.drawwire is not None
        if found:
            self._event("info", found)
        how = "captured again" if again else "captured"
        self._event("reference", f"{self.info.reference} {how} at qm {np.round(qm, 4).tolist()}"
                    + (" (the draw-wire zeroed there; it replaces the earlier reference)"
                       if again else ""))
        return qm

    def _reference_retried(self, what: str, step):
        """``step(attempt)`` (0-based), retried after a DeviceError the way a pose is
        (:meth:`_measure`): a ``fault`` event naming the device, a pause
        (:func:`station.session.device_loss.backoff`), the rig recovered, and ``step`` again
        from its start (it returns the arm where it began and takes every reading
        anew), at most :attr:`reference_retries` times. Then
        :func:`station.session.device_loss.probe` tells a device gone (:class:`DeviceLost`,
        naming it and what to check) from a step that kept failing (its last error).
        The step cannot be skipped: nothing is measured without it. Faults are
        recorded in the trace (its header written first where there is none yet: a
        trace without a reference record resumes with the reference step)."""
        rig = self._rig()
        attempt = 0
        first = None
        while True:
            try:
                closed = device_loss.not_connected(rig)     # a reconnection that failed
                if closed is not None:
                    raise closed
                return step(attempt)
            except DeviceError as e:
                first = time.monotonic() if first is None else first
                self._ensure_trace()
                self._event("fault", f"{what}, attempt {attempt + 1}: "
                            f"{describe_error(e, self.units)}", device=e.device, step=what)
                if (attempt >= self.reference_retries
                        and time.monotonic() - first >= self.retry_window):
                    self._raise_if_lost(rig, e)              # the device, or this step?
                    raise
                attempt += 1
                self._pause_to_retry(what, attempt, step=what)

    def _raise_if_lost(self, rig, error: DeviceError) -> None:
        """After retries: raise :class:`DeviceLost` (with a ``lost`` event) where the
        device itself is gone (:func:`station.session.device_loss.probe`), else return."""
        lost = device_loss.probe(rig, error, self.simulated)
        if lost is not None:
            self._event("lost", str(lost), device=lost.device)
            raise lost from error

    def _pause_to_retry(self, what: str, attempt: int, **extra) -> None:
        """Before retry ``attempt`` (1-based) of ``what``: a ``retry`` event, the backoff
        pause (:func:`station.session.device_loss.backoff`: a short outage passes) and the rig
        recovered."""
        pause = device_loss.backoff(attempt)
        self._event("retry", f"{what}: retry {attempt} in {pause:g} s", **extra)
        time.sleep(pause)
        self._recover()

    def reference_offset(self, qm=None) -> float | None:
        """Distance (m, nominal model) from the reference ``qm`` (default: the captured
        one) to the suggested point; None without a reference step."""
        target, _, _ = self.reference_target()
        qm = self.reference_qm if qm is None else qm
        if target is None or qm is None:
            return None
        a = self.robot.fk(np.asarray(qm, dtype=float), self.nominal)[0, :3]
        b = self.robot.fk(np.asarray(target, dtype=float), self.nominal)[0, :3]
        return float(np.linalg.norm(a - b))

    def rezero_at_reference(self) -> None:
        """After a restart: drive back to the recorded reference and check the
        draw-wire there. One that kept its zero reads the reference's ``tare`` again
        (within 4 standard errors and two counts) and is left alone: every pose keeps
        the one ``distance_off``. One that lost it (power-cycled) is zeroed again; that
        new zero is another noisy reading, said in an event (docs/methods.md)."""
        if self.reference_qm is None or self._rig().drawwire is None:
            return
        tare = (self.reference_record or {}).get("tare")
        target = [float(v) for v in self.reference_qm]

        def check(attempt: int):
            """Back at the reference, read the draw-wire; zero it where it lost its zero.
            A fault anywhere: all of it again (the zero where it is read anew)."""
            self.move_to(target)
            now = _tare(self.rig.snapshot())
            if tare is not None:
                se = math.hypot(tare["std"] / math.sqrt(max(tare["samples"], 1)),
                                now["std"] / math.sqrt(max(now["samples"], 1)))
                tol = 4 * se + 2 * self.config.drawwire.metres_per_count
                if abs(now["distance"] - tare["distance"]) <= tol:
                    return now, True
            self.rig.zero_drawwire()
            return now, False

        now, kept = self._reference_retried("the return to the reference", check)
        if kept:
            self._event("reference", f"back at the reference: draw-wire reads "
                        f"{now['distance']:.6g} m (at capture {tare['distance']:.6g} m): "
                        "it kept its zero", tare=now)
            self.zeroed = True
            return
        self._event("warning", f"back at the reference: draw-wire read {now['distance']:.6g} m "
                    f"(at capture {tare['distance'] if tare else float('nan'):.6g} m): it lost "
                    "its zero and was zeroed again; the poses measured from now on carry that "
                    "new zero's reading noise (a common offset of about one reading's std)",
                    tare=now)
        self.zeroed = True

    def redo(self) -> resume.Redo:
        """What must come before the next measurement (:func:`station.recording.resume.redo`):
        capture the reference, return to it and re-zero, plan, measure skipped poses again."""
        return resume.redo(self)

    # -- guided touching ----------------------------------------------------------------------
    @property
    def touching(self) -> bool:
        """True for the methods measured by guided touching (a ``touch`` callback)."""
        return self.method in planner.TOUCH_METHODS

    @property
    def plane(self) -> np.ndarray | None:
        """sm-plane: the plane ``(a, b, c)`` given as start values (None if not given)."""
        if not all(k in self.extra for k in planner.PLANE):
            return None
        return np.array([self.extra[k] for k in planner.PLANE])

    @property
    def touch_instructions(self) -> str:
        return planner.touch_instructions(self.method)

    def group_of(self, pose: PlannedPose) -> list[PlannedPose]:
        """The planned poses of ``pose``'s pair (sm-self-redundancy), in visiting order."""
        if pose.group is None:
            return [pose]
        return [p for p in self.plan_poses if p.group == pose.group]

    def measured_record(self, index: int) -> dict | None:
        """The recorded pose of plan index ``index`` (None if not measured)."""
        return self.measured.get(index)

    def missing_known(self) -> list[str]:
        """Parameters that must be known (not identifiable, influencing) but were not
        given as start values."""
        return [k for k in planner.MUST_KNOW.get(self.method, ()) if k not in self.known]

    # -- planning -------------------------------------------------------------------------------
    @property
    def pending(self) -> list[PlannedPose]:
        return resume.pending(self.plan_poses, self.measured, self.skipped, self._held)

    @property
    def _done(self) -> int:
        return len(self.measured) + len(self.skipped) + len(self._held)

    @property
    def tilt_range(self):
        """A robot file's sm-distance-tilt: ``(roll, pitch, mount)`` of the tool
        inclinometer (its ranges in rad from the station config, None where not stated;
        its mounting's start values) for planning (:func:`station.planning.serial_plan.readable`);
        None where no range is stated."""
        ranges = plausibility.sensor_ranges(self.config)
        if not (self.serial and self.method == "sm-distance-tilt") or not ranges:
            return None
        return (ranges.get("roll"), ranges.get("pitch"),
                (self.extra.get("mount_x", 0.0), self.extra.get("mount_y", 0.0)))

    @property
    def inclinometer_channels(self) -> tuple[str, ...]:
        """The inclinometer channels this session's method fits."""
        if self.serial:
            return ("roll", "pitch") if self.method == "sm-distance-tilt" else ()
        return plausibility.INCLINOMETER_AXES.get(self.method, ())

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

    @property
    def simulated(self) -> bool:
        """True where the devices are a simulator's (no cable to check)."""
        return bool(self.station_record.get("simulator"))

    @property
    def serial(self) -> bool:
        """True for a robot file's arm (station/planning/serial_plan.py plans it)."""
        return self.config.spec is not None

    @property
    def minimum_count(self) -> int:
        if self.serial:     # eq. 60 over what the method identifies on this robot
            if getattr(self, "_min_count", None) is None:
                ref = self.reference_qm if self.reference_qm is not None else \
                    self.reference_target()[0]
                self._min_count = serial_plan.minimum_count(self.method, self.robot,
                                                            self.nominal, ref)
            return self._min_count
        return planner.minimum_count(self.method, self.components)

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
        scale = None
        if self.serial:
            targets, qm, use, design = serial_plan.plan(
                self.method, self.robot, self.nominal, self.reference_qm, self.request,
                qm_range=self.config.envelope.qm_range, tilt_range=self.tilt_range)
            poses = [PlannedPose(i, tuple(map(float, q)), tuple(map(float, X)), u)
                     for i, (q, X, u) in enumerate(zip(qm, targets, use))]
            self._set_plan(poses, replace=True, design=design)
            return poses
        elif self.rounds is not None:
            poses, scale = self.rounds.first_plan(), SCOUT_SCALE
        elif self.robot.name == "agebot-sm":
            start = self.reference_qm
            if start is None and self.rig is not None and all(d.is_open for d in self.rig.devices):
                start = self.qm()
            designs: list = []
            poses = planner.plan_sm(self.method, self.nominal, start, self.request,
                                    plane=self.plane, accept=within_limits(self.config.envelope),
                                    design_out=designs)
            if designs:
                self._set_plan(poses, replace=True, design=designs[0])
                return poses
        else:
            rig, home = self._rig(), None

            def start_step(attempt: int):
                nonlocal home
                if home is None:        # where the wrist stands: its start (home) pose
                    home = [float(v) for v in rig.qm()]
                elif rig.can_move:      # back there after a fault (a test move's)
                    rig.move_to(home)
                found = plausibility.check_wrist(self)      # a flipped sign stops here
                return found, np.array(rig.qm()), self._orientation_now()

            found, home_qm, home_X = self._reference_retried("the wrist's start step",
                                                             start_step)
            if found:
                self._ensure_trace()
                self._event("info", found)
            self.wrist.request = self.request    # the operator may have changed count, seed
            poses, wrist = self.wrist.scout(home_qm, home_X)
            self._set_plan(poses, replace=True, wrist=wrist)
            return poses
        self._set_plan(poses, replace=True, box_scale=scale)
        return poses

    def _orientation_now(self) -> np.ndarray:
        r = self._rig().read()
        if "yaw" in r:
            return euler_from_ypr(r["roll"], r["pitch"], r["yaw"])
        return np.array([r.get("roll", 0.0), r.get("pitch", 0.0), 0.0])

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
    def rounds(self) -> ArmRounds | None:
        """The arm's round plan and envelope model (distance methods, with
        ``PlanRequest.grow`` or resuming such a session), else None."""
        plans = [e for e in self.events if e.get("kind") == "plan"]
        grow = (any("box_scale" in e for e in plans) if plans       # a resumed one goes on
                else self.request.grow)                              # as it was planned
        if (self._rounds is None and grow and self.method in ROUND_METHODS
                and self.robot.name == "agebot-sm"):
            self._rounds = ArmRounds(self)
        return self._rounds

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
        rnd = poses[0].round if poses else 0
        if self.robot.name == "agebot-pm" and rnd == 0:
            text = (f"scout round: planned {len(poses)} poses near home; the wrist's start "
                    "model fitted to their readings plans the next rounds, each in a wider box "
                    f"up to the report's (eq. 60 minimum {self.minimum_count} {unit} in all)")
        elif self.robot.name == "agebot-pm":
            before = len(self.plan_poses) - len(poses)
            text = (f"round {rnd}: planned {len(poses)} poses ({n_val} held out for validation) "
                    f"after the {before} of the earlier rounds, {len(self.plan_poses)} in all so "
                    f"far (eq. 60 minimum {self.minimum_count} {unit})")
        elif box_scale is not None:      # the arm's rounds: this round, then the whole
            fit_all, held_all = self.rounds.fit_total(), self.rounds.totals()[1]
            text = (("scout round" if rnd == 0 else f"round {rnd}") + f": planned {len(poses)} "
                    f"poses ({n_val} held out for validation), {len(self.plan_poses)} planned "
                    f"so far; the rounds plan {fit_all} to fit + {held_all} held out in all "
                    f"(eq. 60 minimum {self.minimum_count} {unit} to fit)")
        else:
            text = (f"planned {len(poses)} poses ({n_val} held out for validation; "
                    f"eq. 60 minimum {self.minimum_count} {unit}{how})")
        design = extra.get("design") or (extra.get("wrist") or {}).get("design")
        if design:
            text += "; " + design_text(design, self.units)
            self.last_design = design
        self._event("plan", text, poses=[p.record() for p in poses], replace=replace, **extra)
        self._notify("state", "planned")

    @property
    def rounds_complete(self) -> bool:
        """False while the wrist's growing box (station/planning/wrist_plan.py) or the arm's rounds
        (station/planning/arm_rounds.py) have rounds to plan."""
        if self.rounds is not None:
            return self.rounds.planned_last()
        return self.wrist is None or (self.wrist.final and not self.wrist.replan)

    def _plan_next_round(self) -> bool:
        """Wrist: after each round, refit the start model to every recorded pose and plan
        the next, wider round (:class:`station.planning.wrist_plan.WristPlanner`); raises
        :class:`station.planning.wrist_plan.WristStopped` (recorded as an event) where it cannot."""
        if self.rounds is not None:
            return self.rounds.next_round()
        if self.rounds_complete:
            return False
        records = sorted(self.measured.values(), key=lambda r: r["index"])
        self._event("info", f"fitting the wrist's start model to {len(records)} poses")
        fit_done = sum(r.get("use", "fit") == "fit" for r in records)
        nxt = max(p.index for p in self.plan_poses) + 1
        last = records[-1]["qm"] if records else None
        try:
            out = self.wrist.next_round(records, nxt, last, fit_done, len(records) - fit_done)
        except StationError as e:
            self._event("stop", str(e))
            raise
        if out is None:
            return False
        poses, wrist = out
        self._event("info", f"wrist round {wrist['round']}: box +-{wrist['box_deg']:.1f} deg "
                    f"(measured region {wrist['reach_deg']:.1f} deg)")
        self._set_plan(poses, replace=False, wrist=wrist)
        return True

    def _wrist_watch(self, pose: PlannedPose, rec: dict) -> bool:
        """Wrist: True if the measured orientation is where the model predicts; else the
        pose and the rest of its round are dropped and the next round re-planned."""
        problem = self.wrist.watch(pose, rec)
        if problem is None:
            return True
        self.wrist.tripped()
        self._event("envelope", f"{problem}: not recorded; the rest of round {pose.round} is "
                    "dropped and re-planned from the poses recorded")
        self._skip(pose, f"pose {pose.index} not recorded (outside the model's tolerance)",
                   resume.DROPPED)
        for p in self.pending:
            if p.round == pose.round:
                self._skip(p, f"pose {p.index} dropped: round {pose.round} is re-planned",
                           resume.DROPPED)
        return False

    # -- measuring ---------------------------------------------------------------------------------
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
                while self._pause.is_set() and not self._abort.is_set():
                    time.sleep(0.05)
                if self._abort.is_set():
                    self._event("abort", "aborted by the operator")
                    raise SessionAborted("aborted; the trace is intact, resume to continue")
                if self._measure(pose):
                    recorded += 1
            if self.pending:      # re-planned meanwhile (an envelope stop)
                continue
            if not self._plan_next_round():
                break
        self._notify("state", "measured")
        return recorded

    def _progress(self, pose: PlannedPose, readings=None, message: str = "") -> Progress:
        """Progress at ``pose``; the wrist's counts are per round (scout, main)."""
        p = Progress(self._done, len(self.plan_poses), pose, dict(readings or {}), message)
        if self.robot.name == "agebot-pm":
            same = [q.index for q in self.plan_poses if q.round == pose.round]
            done = sum(i in self.measured or i in self.skipped for i in same)
            stage = "scout" if pose.round == 0 else f"round {pose.round}"
            p = dataclasses.replace(p, stage=stage,
                                    stage_done=done, stage_total=len(same))
        return p

    def _measure(self, pose: PlannedPose) -> bool:
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
                snap = rig.snapshot()
                beyond = plausibility.range_problems(
                    self.config, {k: snap.mean.get(k) for k in self.inclinometer_channels},
                    f"at pose {pose.index}")
                if beyond:       # the sensor cannot read there: nothing to record
                    self._skip(pose, f"pose {pose.index} not recorded: " + "; ".join(beyond),
                               resume.DROPPED)
                    return False
                rec = self._pose_record(pose, snap)
                if self.wrist is not None and not self._wrist_watch(pose, rec):
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
        """Move to ``pose`` inside the envelope (:mod:`station.planning.envelope`): a pose beyond
        the config's actuator limits is skipped unmoved; the arm's move is watched
        against its current model, and where it departs the arm stops, the pose is
        skipped and the round re-planned. False where the pose was not reached."""
        env = self.config.envelope
        why = limit_violation(pose.qm, env)
        if why is not None:
            self._skip(pose, f"pose {pose.index} skipped before moving: {why}", resume.DROPPED)
            return False
        predict = self._ranged(self.rounds.predictor() if self.rounds is not None else None)
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
            self.rounds.replan_after_stop(pose.round, self.rounds.scale_of(pose))
            return False
        if halts:
            self._event("info", f"pose {pose.index}: the move was halted {halts} times where "
                        "the readings departed while moving but agreed with the model at rest "
                        "(a sensor later than the config's [envelope] latency); it went on")
        return True

    def _require_touch(self) -> None:
        if self.touching and self.touch is None:
            raise StationError(f"{self.method} is measured by guided touching: the session "
                               "needs a touch callback (the operator who brings the tool into "
                               "contact; app.py run --simulate has a simulated one)")

    def _touch(self, pose: PlannedPose) -> None:
        self._notify("progress", self._progress(pose, message=f"touching at pose {pose.index}"))
        self.touch(self, pose)

    def _skip(self, pose: PlannedPose, message: str, reason: str) -> None:
        """Skip ``pose`` (``reason``: :data:`station.recording.resume.FAULT` or ``NO_CONTACT``; a
        fault's poses are measured again on resume); for a pair, also its partners not
        written yet (touched ones are dropped: a pair is written whole)."""
        self.skipped.add(pose.index)
        self._event("skip", message, plan_index=pose.index, reason=reason)
        for p in self.group_of(pose):
            if p.index not in self.measured and p.index not in self.skipped:
                self._held.pop(p.index, None)
                self.skipped.add(p.index)
                self._event("skip", f"pose {p.index} skipped with its pair partner {pose.index}",
                            plan_index=p.index, reason=reason)

    def _recover(self) -> None:
        """Before a retry or after a skip: reset a faulted drive, or reconnect a device
        that dropped (:meth:`drivers.rig.Rig.recover`)."""
        try:
            self.rig.recover()
        except DeviceError as e:
            self._event("fault", f"recovery failed: {e}", device=e.device)

    def _pose_record(self, pose: PlannedPose, snap) -> dict:
        m = snap.mean
        n = self.robot.n_actuators
        qm = [m[f"qm{i + 1}"] for i in range(n)]
        rec = {"record": "pose", "index": self._next_index, "plan_index": pose.index,
               "qm": qm, "target": list(pose.target), "use": pose.use, "t": snap.t_start,
               "samples": snap.samples, "std": {k: v for k, v in snap.std.items()}}
        if pose.group is not None:
            rec["group"] = int(pose.group)
        if self.method in ("sm-distance", "sm-distance-tilt"):
            rec["distance"] = m["distance"]
        if self.method == "sm-distance-tilt":     # a robot file's: the tool inclinometer's two axes
            rec["tilt"] = [m["roll"], m["pitch"]] if self.serial else m["tilt"]
        elif self.method == "sm-distance" and not self.serial and "tilt" in m:
            rec["tilt"] = m["tilt"]    # beside: the rounds' watch learns from it (not fitted)
        if self.method == "pm-tilt":
            rec["tilt"] = [m["roll"], m["pitch"]]
        if self.method in ("pm-ik", "pm-fk"):
            if "yaw" not in m:
                raise ConfigError("pm-ik/pm-fk need the sensor's yaw: map roll, pitch and yaw in "
                                  "[inclinometer.axes] (or use pm-tilt, which needs only roll "
                                  "and pitch)", source=self.config.source, key="inclinometer.axes")
            X = euler_from_ypr(m["roll"], m["pitch"], m["yaw"])
            comps = self.components if self.method == "pm-fk" else COMPONENTS
            rec["orientation"] = [float(X[COMPONENTS.index(c)]) for c in comps]
        return rec

    # -- calibration, validation, export ------------------------------------------------------------
    def calibrate(self, callback=None, accept_poor_fit: bool | None = None) -> BatchOutcome:
        """Calibrate the recorded fit poses (Algorithm 2) and pass the fit-quality gate
        (:mod:`station.fitting.gate`; a failed gate raises unless ``accept_poor_fit``, default
        the session's); ``callback(k, iteration)`` after every iteration
        (:class:`calibration.solver.Iteration`: live plots)."""
        if accept_poor_fit is None:
            accept_poor_fit = self.accept_poor_fit
        if self._writer is not None:
            self._writer.close()
            self._writer = None
        try:
            trace = read_trace(self.trace_path)
        finally:
            self._writer = TraceWriter.resume(self.trace_path)
        if self.method == "sm-self-redundancy":
            self._drop_lone_poses(trace)
            n_fit = len({p["group"] for p in trace.fit_poses})
            unit = "pairs"
        else:
            n_fit, unit = len(trace.fit_poses), "poses"
        if n_fit < self.minimum_count:
            self._event("warning", f"{n_fit} {unit} recorded; eq. 60 recommends at least "
                        f"{self.minimum_count}")
        self._notify("state", "calibrating")
        try:
            self.outcome = calibrate(trace, callback=callback, accept_poor_fit=accept_poor_fit)
        except FitQualityError as e:
            self._event("fit-quality", str(e))
            raise
        q = self.outcome.quality
        for o in q.outliers:
            self._event("outlier", f"pose {o['pose']} {o['channel']} left out of the fit "
                        f"(studentized residual {o['t']:.3g} > {o['threshold']:.3g})")
        if not q.passed:
            self._event("fit-quality", "accepted by the operator: " + q.summary())
        self._event("calibrated", self.outcome.result.message)
        self._notify("state", "calibrated")
        return self.outcome

    def _drop_lone_poses(self, trace) -> None:
        """Pairs whose partner was skipped: leave the lone pose out of the calibration."""
        count: dict = {}
        for p in trace.poses:
            key = (p.get("use", "fit"), p["group"])
            count[key] = count.get(key, 0) + 1
        lone = [p for p in trace.poses if count[(p.get("use", "fit"), p["group"])] < 2]
        if lone:
            trace.poses[:] = [p for p in trace.poses if p not in lone]
            self._event("warning", "left out of the calibration (their pair partner was not "
                        "recorded): poses " + ", ".join(str(p["index"]) for p in lone))

    def validate(self) -> list[dict]:
        """Errors on the held-out poses before (start values) and after calibration,
        per measured channel."""
        if self.outcome is None:
            raise StationError("calibrate first")
        self.validation = (self.outcome.validation if self.outcome.validation is not None
                           else validation_errors(self.outcome))
        if self.validation:
            from station.outputs.report_sections import validation_headline

            self._event("validated", validation_headline(self.validation, self.units))
        return self.validation

    def export(self) -> dict:
        """Write ``params.json`` (atomically, with checksum) and ``report.html``."""
        if self.outcome is None:
            raise StationError("calibrate first")
        if self.validation is None:
            self.validate()
        o = self.outcome
        doc = outcome_document(o, str(self.trace_path))
        if self.serial:   # a robot file's calibration keeps it
            doc["robot_file"] = dict(self.config.spec.source)
        doc = _writing(self.out / PARAMS, write_params, self.out / PARAMS, doc)
        self._event("export", f"parameter file {self.out / PARAMS} ({doc['checksum']})")
        urdf = self._export_urdf(doc) if self.serial else None
        from station.outputs.report import write_report

        o = self.outcome = dataclasses.replace(o, document=doc)
        events = list(self.events)
        _writing(self.out / REPORT, write_report, self.out / REPORT, o,
                 validation=self.validation, events=events, units=self.units,
                 session={"robot": self.robot.name, "method": self.method,
                          "station config": self.config.source or "",
                          "poses measured": len(self.measured),
                          "poses skipped": len(self.skipped)})
        self._event("report", f"report {self.out / REPORT}")
        self.exported = {"params": str(self.out / PARAMS), "report": str(self.out / REPORT),
                         "trace": str(self.trace_path), "checksum": doc["checksum"]}
        if urdf:
            self.exported["urdf"] = urdf
        self._notify("state", "exported")
        return self.exported

    def _export_urdf(self, doc: dict) -> str | None:
        """A robot file's calibration as URDF (``calibrated.urdf``, station/outputs/export.py);
        None, said in an event, where a calibrated ratio k is not 1."""
        from drivers.atomic import write_atomic
        from station.outputs.export import calibrated_model, urdf_text

        path = self.out / URDF
        try:
            text = urdf_text(*calibrated_model(doc, str(self.out / PARAMS)))
        except ConfigError as e:
            self._event("warning", f"no URDF: {e}")
            return None
        write_atomic(path, text.encode("utf-8"))
        self._event("export", f"URDF {path}")
        return str(path)

    # -- everything, as an operator would do it --------------------------------------------------------
    def run(self) -> dict:
        """The whole session unattended (headless): reference at the planned point,
        plan, measure, calibrate, validate, export. Resumes where a trace stopped."""
        self._require_touch()
        if self.rig is None or not all(d.is_open for d in self.rig.devices):
            self.connect()
        self._quiet = self.finished    # the result shown again, nothing appended
        todo = self.redo()
        if todo.capture_reference:
            qm, role, _ = self.reference_target()
            self._event("info", f"moving to the {role} for the reference step")
            self.capture_reference(qm)
        elif todo.rezero:
            self.rezero_at_reference()
        if todo.plan:
            self.plan()
        self.execute()
        self.calibrate()
        self.validate()
        if self.finished:      # measured and exported before: the files stay as they are
            self.exported = {"params": str(self.out / PARAMS), "report": str(self.out / REPORT),
                             "trace": str(self.trace_path),
                             "checksum": read_params(self.out / PARAMS)["checksum"]}
            return self.exported
        return self.export()


def _writing(path, write, *args, **kwargs):
    """``write(*args, **kwargs)`` with an OSError (a full disk) as one line naming ``path``."""
    try:
        return write(*args, **kwargs)
    except OSError as e:
        raise StationError(f"{path}: cannot write: {e.strerror or e}; the trace is intact: "
                           "free space, then run the session again to export") from None


def _tare(snap) -> dict:
    """The draw-wire's averaged reading of a snapshot: ``distance`` (m), ``std`` (m, of
    one reading), ``samples``."""
    return {"distance": float(snap.mean["distance"]), "std": float(snap.std.get("distance", 0.0)),
            "samples": int(snap.samples)}

