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

Crash safety: the trace (file-formats.md) is the session's only state. The
plan is recorded as an ``event`` of kind ``plan`` (with its poses), each
measured pose carries ``plan_index``, skipped poses an event of kind ``skip``;
so :class:`Session` on an existing trace continues with the poses not yet
measured, whatever moment the previous process died at.

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

from calibration.errors import CalibrationError, ConfigError, StationError
from calibration.methods import METHODS, build
from calibration.robots import get_robot
from calibration.robots.agebot_pm import euler_from_ypr
from drivers.config import StationConfig
from drivers.errors import DeviceError
from station import planner
from station.batch import BatchOutcome, calibrate, frame_statement
from station.params_file import params_document, write_params
from station.planner import PlannedPose, PlanRequest
from station.trace import TraceWriter, read_trace, utc_now

log = logging.getLogger("station.session")

TRACE, PARAMS, REPORT = "trace.jsonl", "params.json", "report.html"
COMPONENTS = ("alpha", "beta", "gamma")


class SessionAborted(StationError):
    """The operator (or the fault policy) aborted; the trace is intact and resumable."""


@dataclass(frozen=True)
class Progress:
    """What the session is doing: pose ``done`` of ``total`` (planned, incl. held-out),
    the pose being measured and the latest readings (channel -> value)."""

    done: int
    total: int
    pose: PlannedPose | None
    readings: dict = field(default_factory=dict)
    message: str = ""


Observer = Callable[[str, object], None]           # (kind, payload): "progress", "event", "state"
FaultPolicy = Callable[[PlannedPose, DeviceError, int], str]   # -> "retry" | "skip" | "abort"


def retry_then_skip(retries: int = 2) -> FaultPolicy:
    """The headless policy: retry a faulty pose ``retries`` times, then skip it."""
    def policy(pose, error, attempt):
        return "retry" if attempt < retries else "skip"
    return policy


class Session:
    """One calibration session of one robot with one method, recorded in ``out_dir``.

    config:   the station config (endpoints resolved). method: a session method
              (:data:`station.planner.SESSION_METHODS`).
    out_dir:  folder of ``trace.jsonl``, ``params.json``, ``report.html``; an existing
              trace there is resumed (its robot and method must match).
    request:  pose count, held-out count, seed (:class:`~station.planner.PlanRequest`).
    observer: ``observer(kind, payload)`` for progress, events and state changes.
    fault_policy: what to do when a pose fails (default: retry twice, then skip).
    rig:      devices to use (default: built from ``config`` at :meth:`connect`).
    nominal:  parameter name -> start value over the robot model's nominal (values the
              engineer knows, e.g. a gear ratio from the datasheet); a resumed trace
              keeps its own.
    """

    def __init__(self, config: StationConfig, method: str, out_dir, *,
                 request: PlanRequest | None = None, observer: Observer | None = None,
                 fault_policy: FaultPolicy | None = None, rig=None,
                 nominal: dict | None = None):
        planner.check_method(method)
        mi = METHODS[method]
        if config.robot != mi.robot:
            raise ConfigError(f"the station is for {config.robot}, method {method} for {mi.robot}",
                              source=config.source, key="robot")
        self.config, self.method, self.info = config, method, mi
        self.robot = get_robot(mi.robot)
        self.out = Path(out_dir)
        self.request = request or PlanRequest()
        self.observer = observer
        self.fault_policy = fault_policy or retry_then_skip()
        self.rig = rig
        self.nominal = self.robot.params(dict(nominal or {}), source="nominal")
        self.components = tuple(self.request.components) if method == "pm-fk" else None
        self.reference_qm: np.ndarray | None = None
        self.plan_poses: list[PlannedPose] = []
        self.measured: dict[int, dict] = {}        # plan index -> pose record
        self.skipped: set[int] = set()
        self.events: list[dict] = []
        self.outcome: BatchOutcome | None = None
        self.validation: list[dict] | None = None
        self.exported: dict | None = None
        self._writer: TraceWriter | None = None
        self._next_index = 0
        self._pause = threading.Event()
        self._abort = threading.Event()
        self.resumed = self.trace_path.exists()
        if self.resumed:
            self._load()

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
        self.nominal = tr.nominal_vector(self.robot)
        if tr.header.get("components"):
            self.components = tuple(tr.header["components"])
        if tr.reference is not None:
            self.reference_qm = np.array(tr.reference["qm"], dtype=float)
        for ev in tr.events:
            self.events.append(ev)
            if ev.get("kind") == "plan":
                poses = [PlannedPose.from_record(r) for r in ev.get("poses", ())]
                self.plan_poses = poses if ev.get("replace", True) else self.plan_poses + poses
            elif ev.get("kind") == "skip" and "plan_index" in ev:
                self.skipped.add(int(ev["plan_index"]))
        for p in tr.poses:
            if "plan_index" in p:
                self.measured[int(p["plan_index"])] = p
        self._next_index = (tr.poses[-1]["index"] + 1) if tr.poses else 0
        self._event("resume", f"resumed: {len(self.measured)} poses recorded, "
                    f"{len(self.pending)} still to measure")

    def _ensure_trace(self) -> TraceWriter:
        if self._writer is None:
            self.out.mkdir(parents=True, exist_ok=True)
            header = {"robot": self.robot.name, "method": self.method,
                      "nominal": self.robot.as_dict(self.nominal),
                      "station": {"config": self.config.source, "software": "calstation",
                                  "devices": [d.name for d in self.rig.devices] if self.rig
                                  else []}}
            if self.components:
                header["components"] = list(self.components)
            self._writer = TraceWriter.create(self.trace_path, header)
        return self._writer

    def _event(self, kind: str, message: str, **extra) -> None:
        rec = {"record": "event", "t": utc_now(), "kind": kind, "message": message, **extra}
        if self._writer is not None:
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

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def readings(self) -> dict[str, float]:
        """One live reading of every channel."""
        return self._rig().read()

    def move_to(self, qm) -> None:
        self._rig().move_to([float(v) for v in qm])

    def jog(self, axis: int, delta: float) -> None:
        """Move actuator ``axis`` (0-based) by ``delta`` actuator units."""
        qm = self._rig().qm()
        qm[axis] += float(delta)
        self.move_to(qm)

    def _rig(self):
        if self.rig is None or not all(d.is_open for d in self.rig.devices):
            raise StationError("the devices are not connected: connect first")
        return self.rig

    # -- reference ------------------------------------------------------------------------------
    @property
    def needs_reference(self) -> bool:
        return self.info.reference is not None

    def reference_target(self):
        """``(qm, role, instructions)`` for the reference step (qm None: no reference)."""
        return planner.reference_pose(self.method, self.nominal)

    def capture_reference(self) -> np.ndarray:
        """Record the current pose as the reference: zero the draw-wire (the cable is
        attached here) and write the reference record."""
        if not self.needs_reference:
            raise StationError(f"method {self.method} has no reference step")
        if self.reference_qm is not None:
            raise StationError("the reference is already captured (start a new session to "
                               "capture another)")
        rig = self._rig()
        if rig.drawwire is not None:
            rig.zero_drawwire()
        qm = np.array(rig.qm(), dtype=float)
        w = self._ensure_trace()
        w.append({"record": "reference", "role": self.info.reference, "qm": qm.tolist(),
                  "t": utc_now()})
        self.reference_qm = qm
        self._event("reference", f"{self.info.reference} captured at qm "
                    f"{np.round(qm, 4).tolist()}")
        return qm

    def rezero_at_reference(self) -> None:
        """After a restart: drive back to the recorded reference and zero the draw-wire
        there again (the cable is still attached at the reference point; a sensor
        that was power-cycled lost its zero, one that was not reads ~0 anyway)."""
        if self.reference_qm is None or self._rig().drawwire is None:
            return
        self.move_to(self.reference_qm)
        before = self.rig.drawwire.read().values["distance"]
        self.rig.zero_drawwire()
        self._event("reference", f"back at the reference: draw-wire read {before:.6g} m, "
                    "zeroed again")

    # -- planning -------------------------------------------------------------------------------
    @property
    def pending(self) -> list[PlannedPose]:
        return [p for p in self.plan_poses if p.index not in self.measured
                and p.index not in self.skipped]

    @property
    def minimum_count(self) -> int:
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
        if self.robot.name == "agebot-sm":
            poses = planner.plan_sm(self.method, self.nominal, self.reference_qm, self.request)
        else:
            home_qm = np.array(self._rig().qm())
            home_X = self._orientation_now()
            poses = planner.plan_pm_scout(home_qm, home_X, self.request)
        self._set_plan(poses, replace=True)
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

    def _set_plan(self, poses: list[PlannedPose], replace: bool) -> None:
        if replace:
            self.plan_poses = list(poses)
        else:
            self.plan_poses += poses
        n_val = sum(p.use == "validation" for p in poses)
        self._ensure_trace()
        self._event("plan", f"planned {len(poses)} poses ({n_val} held out for validation; "
                    f"eq. 60 minimum {self.minimum_count})",
                    poses=[p.record() for p in poses], replace=replace)
        self._notify("state", "planned")

    def _plan_next_round(self) -> bool:
        """Wrist: after the scout round, plan the main round with the fitted start model."""
        if self.robot.name != "agebot-pm" or any(p.round == 1 for p in self.plan_poses):
            return False
        scout = [self.measured[p.index] for p in self.plan_poses
                 if p.round == 0 and p.index in self.measured]
        if len(scout) < 6:
            raise StationError(f"only {len(scout)} scout poses were measured; the wrist's start "
                               "model needs at least 6")
        qm = np.array([p["qm"] for p in scout])
        ch = "tilt" if self.method == "pm-tilt" else "orientation"
        readings = np.array([p[ch] for p in scout])
        comps = self.components or COMPONENTS
        self._event("info", f"fitting the wrist's start model to {len(scout)} scout poses")
        xi = planner.pm_start_model(qm, readings, self.method, comps)
        nxt = max(p.index for p in self.plan_poses) + 1
        poses = planner.plan_pm_main(xi, self.method, nxt, qm[-1], self.request, len(scout))
        self._set_plan(poses, replace=False)
        return True

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
        self._notify("state", "measuring")
        while True:
            for pose in self.pending:
                while self._pause.is_set() and not self._abort.is_set():
                    time.sleep(0.05)
                if self._abort.is_set():
                    self._event("abort", "aborted by the operator")
                    raise SessionAborted("aborted; the trace is intact, resume to continue")
                if self._measure(pose):
                    recorded += 1
            if not self._plan_next_round():
                break
        self._notify("state", "measured")
        return recorded

    def _measure(self, pose: PlannedPose) -> bool:
        rig = self._rig()
        attempt = 0
        while True:
            self._notify("progress", Progress(len(self.measured) + len(self.skipped),
                                              len(self.plan_poses), pose,
                                              message=f"moving to pose {pose.index}"))
            try:
                rig.move_to(pose.qm)
                snap = rig.snapshot()
                rec = self._pose_record(pose, snap)
                break
            except DeviceError as e:
                self._event("fault", f"pose {pose.index}, attempt {attempt + 1}: {e}",
                            plan_index=pose.index, device=e.device)
                action = self.fault_policy(pose, e, attempt)
                if action == "abort":
                    self._event("abort", f"aborted at pose {pose.index} after a fault")
                    raise SessionAborted(f"aborted after a fault: {e}") from e
                if action == "skip":
                    self.skipped.add(pose.index)
                    self._event("skip", f"pose {pose.index} skipped", plan_index=pose.index)
                    self._recover(e)      # the next pose must not meet the same fault
                    return False
                attempt += 1
                self._event("retry", f"pose {pose.index}: retry {attempt}",
                            plan_index=pose.index)
                self._recover(e)
        self._ensure_trace().append(rec)
        self.measured[pose.index] = rec
        self._next_index += 1
        self._notify("progress", Progress(len(self.measured) + len(self.skipped),
                                          len(self.plan_poses), pose, dict(snap.mean),
                                          f"pose {pose.index} recorded"))
        return True

    def _recover(self, error: DeviceError) -> None:
        """Before a retry: reset a faulted drive, or reconnect a device that dropped."""
        rig = self.rig
        try:
            if "fault" in str(error).lower() and rig.can_move:
                rig.fault_reset()
            else:
                time.sleep(0.2)
                rig.reconnect()
        except DeviceError as e:
            self._event("fault", f"recovery failed: {e}", device=e.device)

    def _pose_record(self, pose: PlannedPose, snap) -> dict:
        m = snap.mean
        n = self.robot.n_actuators
        qm = [m[f"qm{i + 1}"] for i in range(n)]
        rec = {"record": "pose", "index": self._next_index, "plan_index": pose.index,
               "qm": qm, "target": list(pose.target), "use": pose.use, "t": snap.t_start,
               "samples": snap.samples, "std": {k: v for k, v in snap.std.items()}}
        if self.method in ("sm-distance", "sm-distance-tilt"):
            rec["distance"] = m["distance"]
        if self.method == "sm-distance-tilt":
            rec["tilt"] = m["tilt"]
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
    def calibrate(self, callback=None) -> BatchOutcome:
        """Calibrate the recorded fit poses (Algorithm 2); ``callback(k, iteration)`` after
        every iteration (:class:`calibration.solver.Iteration`: live plots)."""
        if self._writer is not None:
            self._writer.close()
            self._writer = None
        try:
            trace = read_trace(self.trace_path)
        finally:
            self._writer = TraceWriter.resume(self.trace_path)
        n_fit = len(trace.fit_poses)
        if n_fit < self.minimum_count:
            self._event("warning", f"{n_fit} poses recorded; eq. 60 recommends at least "
                        f"{self.minimum_count}")
        self._notify("state", "calibrating")
        self.outcome = calibrate(trace, callback=callback)
        self._event("calibrated", self.outcome.result.message)
        self._notify("state", "calibrated")
        return self.outcome

    def validate(self) -> list[dict]:
        """Errors on the held-out poses before (start values) and after calibration,
        per measured channel."""
        if self.outcome is None:
            raise StationError("calibrate first")
        self.validation = validation_errors(self.outcome)
        if self.validation:
            self._event("validated", "; ".join(
                f"{v['channel']} RMS {_fmt(v['rms_before'])} -> {_fmt(v['rms_after'])} {v['unit']}"
                for v in self.validation))
        return self.validation

    def export(self) -> dict:
        """Write ``params.json`` (atomically, with checksum) and ``report.html``."""
        if self.outcome is None:
            raise StationError("calibrate first")
        if self.validation is None:
            self.validate()
        o = self.outcome
        notes = list(getattr(o.model, "notes", ()) or ())
        doc = params_document(o.result, robot=self.robot.name, nominal=o.model.x0,
                              trace_path=str(self.trace_path), frame=frame_statement(o.trace),
                              notes=notes)
        doc = write_params(self.out / PARAMS, doc)
        self._event("export", f"parameter file {self.out / PARAMS} ({doc['checksum']})")
        from station.report import write_report

        o = self.outcome = dataclasses.replace(o, document=doc)
        events = list(self.events)
        write_report(self.out / REPORT, o, validation=self.validation, events=events,
                     session={"robot": self.robot.name, "method": self.method,
                              "station config": self.config.source or "",
                              "poses measured": len(self.measured),
                              "poses skipped": len(self.skipped)})
        self._event("report", f"report {self.out / REPORT}")
        self.exported = {"params": str(self.out / PARAMS), "report": str(self.out / REPORT),
                         "trace": str(self.trace_path), "checksum": doc["checksum"]}
        self._notify("state", "exported")
        return self.exported

    # -- everything, as an operator would do it --------------------------------------------------------
    def run(self) -> dict:
        """The whole session unattended (headless): reference at the planned point,
        plan, measure, calibrate, validate, export. Resumes where a trace stopped."""
        if self.rig is None or not all(d.is_open for d in self.rig.devices):
            self.connect()
        if self.needs_reference and self.reference_qm is None:
            qm, role, _ = self.reference_target()
            self._event("info", f"moving to the {role} for the reference step")
            self.move_to(qm)
            self.capture_reference()
        elif self.resumed and self.pending and "distance" in self.info.channels:
            self.rezero_at_reference()
        if not self.plan_poses:
            self.plan()
        self.execute()
        self.calibrate()
        self.validate()
        return self.export()


def validation_errors(outcome: BatchOutcome) -> list[dict]:
    """Per channel: RMS and max |error| of the held-out poses before calibration (the
    nominal; for sm-distance-tilt the nominal in the captured base frame) and after
    (empty if the trace holds no held-out poses)."""
    trace = outcome.trace
    if not trace.validation_poses:
        return []
    robot = get_robot(trace.robot)
    if robot.name == "agebot-pm":    # the start values there are already a fit
        x_before = trace.nominal_vector(robot, METHODS[trace.method].extra_params)
    else:
        x_before = np.asarray(outcome.model.x0, dtype=float)
    data = trace.method_data(use="validation")
    opts = {}
    if trace.method in ("pm-fk", "pm-ik", "pm-tilt"):
        opts["start"] = "nominal"
    model = build(trace.method, robot, data, outcome.result.x, **opts)
    out = []
    after = model.evaluate(outcome.result.x)[0]
    try:
        before = model.evaluate(x_before)[0]
        before_note = ""
    except CalibrationError as e:
        before, before_note = None, str(e)
    for k, ch in enumerate(model.channels):
        rows = model.row_channel == k
        a = after[rows]
        rec = {"channel": ch, "unit": _unit(trace.method, ch), "n": int(rows.sum()),
               "rms_after": float(np.sqrt(np.mean(a ** 2))), "max_after": float(np.abs(a).max())}
        if before is not None:
            b = before[rows]
            rec.update(rms_before=float(np.sqrt(np.mean(b ** 2))),
                       max_before=float(np.abs(b).max()))
        else:
            rec.update(rms_before=None, max_before=None, note=before_note)
        out.append(rec)
    return out


def _unit(method: str, channel: str) -> str:
    if channel in ("distance", "x", "y", "z"):
        return "m"
    if method == "pm-ik":
        return "actuator units"
    return "rad"


def _fmt(v) -> str:
    return "n/a" if v is None or (isinstance(v, float) and not math.isfinite(v)) else f"{v:.3g}"
