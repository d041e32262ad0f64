"""The GUI's one link to the station: a :class:`~station.session.session.Session`, its
devices (simulated in their own process with ``--simulate``) and the workers.

Everything that touches a device or solves runs on :attr:`Controller.jobs`
(one worker thread, in order); live readings come from :attr:`Controller.poller`
on a timer. What the session reports through its ``observer`` (called on the
worker) arrives on the GUI thread as the signals below. No widget here: the
pages call these methods and listen to these signals.
"""
from __future__ import annotations

import logging
import threading
from collections.abc import Callable
from pathlib import Path

from PySide6.QtCore import QObject, QTimer, Signal

from station.session.folder import TraceSummary, summarize_folder  # noqa: F401 (the pages')
from station.gui.worker import FaultQuestion, JobRunner, LockedRig, limited_jog, poll_devices
from station.gui.widgets import set_units

log = logging.getLogger("station.gui")

ROBOTS = {"agebot-sm": "AGEBOT serial arm (SM)", "agebot-pm": "AGEBOT wrist (PM)"}
POLL_MS = 400


def iteration_sink(signal):
    """The solver's ``callback(k, iteration)`` as a signal carrying the iteration."""
    def callback(*args):
        signal.emit(args[-1])
    return callback


class Controller(QObject):
    """Owns the simulator, the session and the workers of one GUI.

    simulate: start the simulated devices (``app.py simulate``) for the chosen robot.
    config_path: the station config (default with ``simulate``: the fixture of the robot,
                 or a robot file's default station).
    truth_path: with ``simulate``, the simulator's truth file (a built-in robot's fixture
                by default; a robot file needs one, as ``app.py run --simulate``).

    A robot is a built-in name (:data:`ROBOTS`) or the path of a robot file.
    """

    progressed = Signal(object)        # station.session.execution.Progress
    eventLogged = Signal(dict)         # a trace event {t, kind, message, ...}
    stateChanged = Signal(str)         # "connected", "planned", "measuring", ...
    polled = Signal(object)            # list[DeviceReading] of one polling round
    valuesChanged = Signal(dict)       # channel -> value (after a jog or a pose)
    sessionChanged = Signal()          # a session was opened or closed
    iterated = Signal(object)          # calibration.solver.Iteration (the session's)
    iterated_offline = Signal(object)  # the same, of the Offline page's calibration
    busyChanged = Signal(bool)

    def __init__(self, *, simulate: bool = False, config_path: str | None = None,
                 endpoints_path: str | None = None, sim_seed: int | None = None,
                 settings=None, truth_path: str | None = None,
                 parent: QObject | None = None):
        super().__init__(parent)
        self.truth_path = truth_path
        self.settings = settings        # QSettings: the last session folder
        self.simulate = simulate
        self.config_path = config_path
        self.endpoints_path = endpoints_path
        self.sim_seed = sim_seed
        self.sim = None                 # drivers.sim.simulator_process.SimulatorProcess
        self.sim_robot: str | None = None
        self.config = None              # drivers.config.StationConfig (resolved)
        self.session = None             # station.session.session.Session
        self.rig: LockedRig | None = None
        self.rezeroed = False           # a resumed distance session went back to its reference
        self.last_readings: dict = {}
        self.faults = FaultQuestion(self)
        self.jobs = JobRunner("session", self)
        self.poller = JobRunner("poll", self)
        self.offline = JobRunner("offline", self)
        self.jobs.busyChanged.connect(self.busyChanged)
        self._jog_stop = threading.Event()
        self._timer = QTimer(self)
        self._timer.setInterval(POLL_MS)
        self._timer.timeout.connect(self._poll)
        self._closed = False
        self._last_open: dict = {}

    @property
    def closed(self) -> bool:
        return self._closed

    @property
    def units(self):
        """The display units (:mod:`station.outputs.units`) of the station config in use."""
        from station.outputs.units import MM_DEG, from_config

        return from_config(self.config) if self.config is not None else MM_DEG

    # -- session lifecycle -----------------------------------------------------------
    @property
    def connected(self) -> bool:
        s = self.session
        return bool(s is not None and s.rig is not None and s.rig.devices
                    and all(d.is_open for d in s.rig.devices))

    def robot_of_config(self, path) -> str:
        """The robot of the station config ``path`` (:func:`drivers.config.robot_of_config`)."""
        from drivers.config import robot_of_config

        return robot_of_config(path)

    def open_session(self, *, robot: str, method: str, out_dir, request,
                     on_done: Callable | None = None, on_error: Callable | None = None,
                     nominal: dict | None = None) -> None:
        """Start the devices (the simulator first, with ``simulate``), open a
        :class:`Session` on ``out_dir`` (resuming a trace there) and connect."""
        self._timer.stop()
        self.faults.reopen()
        old = self.session
        # the same folder again (its devices were lost): its steps stay done meanwhile
        same = old is not None and Path(out_dir).expanduser().resolve() == old.out.resolve()
        self.session = old if same else None
        self.rig = None
        self._last_open = dict(robot=robot, method=method, out_dir=out_dir, request=request,
                               nominal=nominal)

        def job():
            if old is not None:
                old.close()
            return self._open(robot, method, Path(out_dir), request, nominal)

        def done(session):
            self.session = session
            self.rezeroed = False
            self._timer.start()
            self.sessionChanged.emit()
            if on_done:
                on_done(session)

        def failed(e):
            self.session = old if same else None     # closed: Connect tries again
            self.sessionChanged.emit()
            if on_error:
                on_error(e)

        self.jobs.submit(job, done, failed)

    @property
    def devices_lost(self) -> bool:
        """The session's devices are gone: the simulator's process ended, or a device
        closed after a reconnection failed. :meth:`reopen` connects anew."""
        s = self.session
        if s is None:
            return False
        if self.simulate and self.sim is not None and not self.sim.alive:
            return True
        return not self.connected

    def reopen(self, on_done: Callable | None = None, on_error: Callable | None = None) -> None:
        """Open the current session's folder again (a simulator started anew where its
        process ended): the trace is resumed, its steps stay done, and a distance
        session goes back to its reference to zero the draw-wire before the next pose."""
        self.open_session(**self._last_open, on_done=on_done, on_error=on_error)

    def _open(self, robot, method, out: Path, request, nominal):
        from drivers.config import check_config_robot, load_station_config
        from drivers.endpoints import load_endpoints, with_endpoints
        from drivers.rig import Rig
        from station.session.session import Session

        station = None
        if self.simulate:       # as app.py run --simulate (station.headless)
            from drivers.sim.server import SimulatorProcess
            from station.simulation.simulated_station import simulated_station

            truth, seed, station = simulated_station(robot, self.truth_path, self.sim_seed)
            if self.sim is not None and not self.sim.alive:     # its process ended
                self.sim.stop()
                self.sim = None
                self.eventLogged.emit({"kind": "info", "message": "the simulated devices' "
                                       "process had ended: the simulator is started anew"})
            if self.sim is not None and self.sim_robot != (robot, truth):
                self.sim.stop()
                self.sim = None
            if self.sim is None:
                self.sim = SimulatorProcess(robot, truth=truth, config=self.config_path,
                                            seed=seed, pose_noise=True)
                self.sim_robot = (robot, truth)
            config = self.sim.station_config()
        else:
            from calibration.errors import ConfigError

            if not self.config_path:
                raise ConfigError("no station config: choose the station's config file, or "
                                  "start the station with --simulate")
            config = load_station_config(self.config_path)
            if self.endpoints_path:
                config = with_endpoints(config, load_endpoints(self.endpoints_path),
                                        source=self.endpoints_path)
        check_config_robot(config, robot)
        self.config = config
        set_units(self.units)
        rig = LockedRig(Rig(config))
        session = Session(config, method, out, request=request, observer=self._observe,
                          fault_policy=self._fault_policy, rig=rig, nominal=nominal,
                          station=station)
        try:
            session.connect()
        except BaseException:
            session.close()
            raise
        self.rig = rig
        return session

    def remember_folder(self, folder) -> None:
        if self.settings is not None:
            self.settings.setValue("last_session", str(folder))
            self.settings.sync()

    def last_folder(self) -> str | None:
        if self.settings is None:
            return None
        value = self.settings.value("last_session")
        return str(value) if value else None

    def close_session(self, on_done: Callable | None = None) -> None:
        self._timer.stop()
        s, self.session = self.session, None

        def job():
            if s is not None:
                s.close()

        def done(_):
            self.sessionChanged.emit()
            if on_done:
                on_done()

        self.jobs.submit(job, done, lambda e: done(None))

    def shutdown(self, timeout_s: float = 20.0) -> None:
        """The window closes: stop jogging and measuring (the trace already holds
        every recorded pose), close the devices, stop the simulator. Blocks."""
        if self._closed:
            return
        self._closed = True
        self._timer.stop()
        self._jog_stop.set()
        self.faults.cancel_all()
        s = self.session
        if s is not None:
            s.abort()
        self.jobs.wait(int(timeout_s * 1000))
        self.poller.wait(3000)
        self.offline.wait(int(timeout_s * 1000))
        if s is not None:
            try:
                s.close()
            except Exception as e:  # noqa: BLE001 - closing must go on
                log.warning("closing the session: %s", e)
        self.session = None
        if self.sim is not None:
            self.sim.stop()
            self.sim = None

    # -- what the session reports (worker thread -> signals) --------------------------------
    def _observe(self, kind: str, payload) -> None:
        if kind == "progress":
            self.progressed.emit(payload)
            if getattr(payload, "readings", None):
                self.valuesChanged.emit(dict(payload.readings))
        elif kind == "event":
            self.eventLogged.emit(dict(payload))
        elif kind == "state":
            self.stateChanged.emit(str(payload))

    def _fault_policy(self, pose, error, attempt) -> str:
        """Ask the operator (:class:`FaultQuestion`); the session recovers the device
        (drive fault reset or reconnect) after a retry or a skip."""
        return self.faults(pose, error, attempt)

    def _poll(self) -> None:
        if self.poller.busy or self.rig is None or self.session is None:
            return
        rig = self.rig
        self.poller.submit(lambda: poll_devices(rig, simulated=self.simulate), self._polled,
                           lambda e: None)

    def _polled(self, result) -> None:
        if result is None:
            return
        values = {}
        for r in result:
            values.update(r.values)
        self.last_readings.update(values)
        self.polled.emit(result)

    # -- device work on the session worker ----------------------------------------------------
    def run(self, fn: Callable, on_done: Callable | None = None,
            on_error: Callable | None = None) -> None:
        """``fn(session)`` on the session worker."""
        s = self.session
        self.jobs.submit(lambda: fn(s), on_done, on_error)

    def jog(self, axis: int, delta: float, speed: float, on_done=None, on_error=None) -> None:
        """A step of ``delta`` actuator units at no more than ``speed`` units/s."""
        self._jog_stop.clear()

        def job(s):
            limited_jog(s, axis, delta, speed, self._jog_stop)
            values = s.readings()
            self.valuesChanged.emit(values)
            return values

        self.run(job, on_done, on_error)

    def jog_continuous(self, axis: int, direction: int, speed: float, on_done=None,
                       on_error=None, dt: float = 0.1) -> None:
        """Move ``axis`` at ``speed`` units/s in ``direction`` until :meth:`stop_jog`."""
        self._jog_stop.clear()

        def job(s):
            import time

            n = 0
            while not self._jog_stop.is_set():
                t0 = time.monotonic()
                s.jog(axis, direction * speed * dt)
                n += 1
                if n % 3 == 0:
                    self.valuesChanged.emit(s.readings())
                rest = dt - (time.monotonic() - t0)
                if rest > 0:
                    time.sleep(rest)
            values = s.readings()
            self.valuesChanged.emit(values)
            return values

        self.run(job, on_done, on_error)

    def stop_jog(self) -> None:
        self._jog_stop.set()

    def move_to(self, qm, on_done=None, on_error=None) -> None:
        def job(s):
            s.move_to(qm)
            values = s.readings()
            self.valuesChanged.emit(values)
            return values

        self.run(job, on_done, on_error)

    def rezero(self, on_done=None, on_error=None) -> None:
        """A resumed distance session: back to the reference, zero the draw-wire there."""
        def job(s):
            with self.rig.lock:
                s.rezero_at_reference()
            return s.readings()

        def done(values):
            self.rezeroed = True
            if on_done:
                on_done(values)

        self.run(job, done, on_error)

    @property
    def needs_rezero(self) -> bool:
        s = self.session
        return bool(s is not None and s.redo().rezero)

    def execute(self, on_done=None, on_error=None) -> None:
        """Measure the pending poses (after a resume of a distance session, first
        back to the reference to zero the draw-wire again)."""
        rezero = self.needs_rezero

        def job(s):
            if rezero:
                with self.rig.lock:
                    s.rezero_at_reference()
                self.rezeroed = True
            return s.execute()

        self.run(job, on_done, on_error)

    def calibrate(self, on_done=None, on_error=None) -> None:
        def job(s):
            outcome = s.calibrate(callback=iteration_sink(self.iterated))
            validation = s.validate()
            return outcome, validation

        self.run(job, on_done, on_error)

    def set_plan(self, poses) -> None:
        """Replace the plan by an edited one (no pose of it measured yet)."""
        self.session.set_plan(list(poses))
