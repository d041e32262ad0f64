"""The station session: reference, IK-planned poses, crash-safe recording,
calibration, validation, export and report. No Qt here: the GUI and the
headless run (``app.py run``) are two faces of this one object.

Workflow (each step may be repeated; the trace records everything), each step a
module of its own that :class:`Session` is made of::

    s = Session(config, "sm-distance-tilt", "out/")   # resumes out/trace.jsonl if present
    s.connect()                                        # opens the devices (drivers.rig.Rig)
    s.move_to(s.reference_target()[0]); s.capture_reference()   # reference.py
    s.plan()                                           # planning_step.py: eq. 60, IK
    s.execute()                                        # execution.py (+ retries.py);
                                                       # flagged readings again: confirmation.py
    s.calibrate(); s.validate(); s.export()            # calibration_step.py

What differs between the robots (the built-in arm, the wrist, a robot file's arm) is
the session's ``kind`` (:mod:`station.session.robot_kinds`), asked by every step.

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

import logging
import threading
from pathlib import Path
from typing import Callable

import numpy as np

from calibration.errors import ConfigError, StationError
from calibration.methods import METHODS, extra_params
from calibration.robots import get_robot
from drivers.check import hint_for
from drivers.config import StationConfig
from station.fitting.outcome import BatchOutcome
from station.outputs.params_file import read_params
from station.outputs.units import describe_error
from station.outputs.units import from_config as units_from_config
from station.planning.envelope import limit_violation
from station.planning.request import MUST_KNOW, PLANE, TOUCH_METHODS, PlanRequest, check_method
from station.planning.request import touch_instructions
from station.recording import resume
from station.recording.lock import FolderLock
from station.recording.planned_pose import PlannedPose
from station.recording.trace import utc_now
from station.recording.trace_writer import TraceWriter
from station.session import device_loss, plausibility
from station.session.calibration_step import CalibrationStep
from station.session.confirmation import ConfirmStep
from station.session.execution import ExecutionLoop
from station.session.folder import PARAMS, REPORT, TRACE, URDF
from station.session.planning_step import PlanningStep
from station.session.reference import ReferenceStep
from station.session.retries import REFERENCE_RETRIES, FaultPolicy, Retries, retry_then_skip
from station.session.kinds import robot_kind

log = logging.getLogger("station.session")

Observer = Callable[[str, object], None]           # (kind, payload): "progress", "event", "state"
Touch = Callable[["Session", PlannedPose], None]   # brings the tool into contact, then returns


class Session(ReferenceStep, PlanningStep, ExecutionLoop, ConfirmStep, CalibrationStep,
              Retries):
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
        check_method(method)
        mi = METHODS[method]
        robot = get_robot(config.robot_model)     # a built-in or the config's robot file
        if robot.kind != mi.kind:
            raise ConfigError(f"the station is for {config.robot} (a {robot.kind} robot), method "
                              f"{method} needs a {mi.kind} one", source=config.source, key="robot")
        if mi.urdf_only and not hasattr(config.spec, "base_link"):
            raise ConfigError(f"{method} calibrates a URDF robot (its instrument frame is a free "
                              f"rigid frame); the station is for {config.robot}: "
                              "robot_file = \"arm.urdf\" with base_link and tip_link",
                              source=config.source, key="robot")
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
        # what differs between the robots: the arm, the wrist, a robot file's arm
        self.kind = robot_kind(self)
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
        made = resume.written_by_a_command(self.trace_path)
        if made is not None:          # nothing of it is touched
            raise ConfigError(f"this trace was written by `{made}`, not recorded by a station "
                              "session: it is not resumed (app.py batch calibrates it); choose "
                              "another folder for the session", source=str(self.trace_path))
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
        self.kind.restore(tr.events)
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
            header.update(self.kind.header())
            self._writer = TraceWriter.create(self.trace_path, header)
        return self._writer

    def _event(self, kind: str, message: str, **extra) -> None:
        rec = {"record": "event", "t": utc_now(), "kind": kind, "message": message, **extra}
        if self._writer is not None and not self._quiet:
            self._writer.append(rec)
        self.events.append(rec)
        log.info("%s: %s", kind, message)
        self._notify("event", rec)

    def _settling(self, what: str, **extra):
        """The ``on_retake`` of :meth:`drivers.rig.Rig.snapshot` for ``what`` (a pose, a
        reference step): each retake of a snapshot still settling is an ``info`` event."""
        def told(error, wait: float) -> None:
            self._event("info", f"{what}: {describe_error(error, self.units)}; still "
                        f"settling after the move, measured again in {wait:g} s", **extra)
        return told

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

    def _rig(self):
        if self.rig is None:
            raise StationError("the devices are not connected: connect first")
        closed = device_loss.not_connected(self.rig)
        if closed is not None:
            raise StationError(f"{closed}: {hint_for(closed.device, self.simulated)}"
                               + ("" if self.simulated else ", then connect again"))
        return self.rig

    @property
    def simulated(self) -> bool:
        """True where the devices are a simulator's (no cable to check)."""
        return bool(self.station_record.get("simulator"))

    @property
    def serial(self) -> bool:
        """True for a robot file's arm (station/planning/serial_plan.py plans it)."""
        return self.config.spec is not None

    # -- guided touching ----------------------------------------------------------------------
    @property
    def touching(self) -> bool:
        """True for the methods measured by guided touching (a ``touch`` callback)."""
        return self.method in TOUCH_METHODS

    @property
    def plane(self) -> np.ndarray | None:
        """sm-plane: the plane ``(a, b, c)`` given as start values (None if not given)."""
        if not all(k in self.extra for k in PLANE):
            return None
        return np.array([self.extra[k] for k in PLANE])

    @property
    def touch_instructions(self) -> str:
        return touch_instructions(self.method)

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
        return [k for k in MUST_KNOW.get(self.method, ()) if k not in self.known]

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
