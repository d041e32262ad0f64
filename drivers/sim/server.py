"""The simulated station as one process: ``python app.py simulate --robot R``.

One :class:`~drivers.sim.robot.SimulatedAgebot` (true parameters from a truth
file) behind the simulated devices, each speaking its real wire protocol:

* CANopen CiA 402 drives (or CiA 406 encoders) on a socketcand hub (TCP, 127.0.0.1);
* the inclinometer on a pseudo-terminal (and ``socket://`` TCP);
* the draw-wire as a Modbus TCP server (and RTU over a pseudo-terminal).

The station config (``--config``, default ``fixtures/stations/sim-<robot>.toml``)
shapes the devices the way the station will expect them: node ids, encoder
resolution, draw-wire scale, offset and word order. The endpoints (cli.md) are
printed as one JSON line and, with ``--endpoints FILE``, written atomically to
that file; they include ``control``, a JSON-lines TCP port through which tests
and demos inject faults and look at the simulated truth::

    {"faults": {"drop_prob": 0.2}}   {"clear": true}   {"state": true}
    {"faults": {"drawwire_answer_first": 3, "drawwire_unanswered": 1}}  (the 4th
                        draw-wire request from now gets no answer; FaultPlan's fields)
    {"move": [qm...]}  (the robot's own controller, for CiA 406 encoders)
    {"drop_drawwire": true}  (close the Modbus TCP connections once)
    {"mocap": {"occluded": ["tool1"], "late_s": 2.0, "drop_next": true, "drop_prob": 0.1}}
                       (the motion capture's faults: drivers/sim/mocap_sim.py)
    {"contact": true}  (what a feeler gauge and the operator's eye tell: the true
                        tool tip and its signed distance to the truth's plane)
    {"pose_noise": false}  (fresh noise per reading from now on, as a real instrument
                        reads; true: a reading at rest a function of the pose again,
                        ``--pose-noise``; the accuracy test reads one pose many times)

``state`` answers the true ``qm``, ``pose``, the draw-wire's ``anchor`` and its
``drawwire_offset`` (m): the noisy length it read when zeroed, so that a reading
where the true distance is 0 is ``-drawwire_offset`` (the truth of the
calibrated ``distance_off``).

``contact`` answers ``"contact": {"tip": [x, y, z], "phi": phi, "distance": d,
"qm": [...]}`` at the robot's true state now: ``tip`` the true end-effector
point (m, base frame), ``phi`` the true angle of the last link (rad), ``distance``
the signed distance (m) from the truth's sm-plane plane ``a x + b y + c z + 1 = 0``,
positive on the side of the base origin (``null`` where the truth has no plane).
The simulated operator of guided touching (:mod:`station.simulation.touch_operator`) watches it.

Every command answers one JSON line: ``{"ok": true, ...}`` or ``{"error": "..."}``.
"""
from __future__ import annotations

import argparse
import json
import logging
import os
import signal
import socket
import socketserver
import sys
import threading
from pathlib import Path
from typing import Any

import numpy as np

from calibration.errors import ConfigError, StationError
from drivers.atomic import write_atomic
from drivers.config import StationConfig, load_station_config
from drivers.drawwire import WORD_ORDER
from drivers.endpoints import with_endpoints
from drivers.sim.cia402_drive import start_canopen_sim
from drivers.sim.drawwire_sim import SimDrawWire
from drivers.sim.faults import FaultPlan
from drivers.sim.inclinometer_sim import SimInclinometer
from drivers.sim.mocap_room import start_mocap
from drivers.sim.robot import LIMIT_NAMES, SimulatedAgebot
from drivers.sim.serial_robot import LIMIT_NAMES as SERIAL_LIMITS
from drivers.sim.serial_robot import SimulatedSerial, is_robot_file, nominal_truth, sim_config
from drivers.sim.truth import SimTruth, load_truth, report_truth

log = logging.getLogger("drivers.sim")

ROOT = Path(__file__).resolve().parents[2]
FIXTURES = ROOT / "fixtures"


def default_config_path(robot: str) -> Path:
    return FIXTURES / "stations" / f"sim-{robot.removeprefix('agebot-')}.toml"


def default_truth_path(robot: str) -> Path:
    return FIXTURES / "truth" / f"{robot}.json"


class SimStation:
    """The simulated robot and its devices, in this process (threads).

    truth:  what the robot really is. config: the station config to look like
    (endpoint placeholders are ignored: the simulator picks free ports).
    inclinometer_hz: frame cycles per second. rtu: also serve Modbus RTU on a pty.
    pose_noise: noise as a function of the pose (:class:`~drivers.sim.robot.SimulatedAgebot`).
    """

    def __init__(self, truth: SimTruth, config: StationConfig, *, seed: int | None = None,
                 inclinometer_hz: float = 100.0, rtu: bool = True, control: bool = True,
                 pose_noise: bool = False):
        if truth.robot == "urdf":        # the true URDF: the config's robot, as built
            from drivers.sim.urdf_truth import same_chain

            why = ("the station config's robot is not a URDF" if config.spec is None or
                   not hasattr(config.spec, "base_link") else same_chain(truth.spec, config.spec))
            if why:
                raise ConfigError(f"the truth file's robot is not the station config's: {why}",
                                  source=config.source, key="robot_file")
        elif config.robot != truth.robot:
            raise ConfigError(f"the station config is for {config.robot}, the truth file for "
                              f"{truth.robot}", source=config.source, key="robot")
        elif truth.spec is not None and (config.spec is None or config.spec.source["sha256"]
                                         != truth.spec.source["sha256"]):
            raise ConfigError("the truth file's robot file is not the station config's",
                              source=config.source, key="robot_file")
        self.truth, self.config = truth, config
        self.plan = FaultPlan(seed=seed)
        cc = config.canopen
        sim = SimulatedSerial if truth.spec is not None else SimulatedAgebot
        self.robot = sim(truth, faults=self.plan, seed=seed,
                                     velocity=cc.profile_velocity or None,
                                     acceleration=cc.profile_acceleration or None,
                                     pose_noise=pose_noise, qm_range=config.envelope.qm_range)
        self._inclinometer_hz, self._rtu, self._control = inclinometer_hz, rtu, control
        self.canopen = self.inclinometer = self.drawwire = self.mocap = None
        self._seed = seed
        self._server: socketserver.ThreadingTCPServer | None = None
        self._stopped = threading.Event()

    # -- lifecycle ---------------------------------------------------------------------
    def start(self) -> "SimStation":
        try:
            cc = self.config.canopen
            self.canopen = start_canopen_sim(
                self.robot.axes, cc.nodes, list(cc.increments_per_unit), self.plan,
                channel=cc.channel, profile=cc.mode, increments=self.robot.encoder_increments,
                supervise=self._limit if (self.truth.robot == "agebot-pm" or
                                          self.truth.spec is not None) else None)
            if self.config.inclinometer is not None:
                self.inclinometer = SimInclinometer(
                    self.robot.inclinometer_angles_deg, rate_hz=self._inclinometer_hz,
                    faults=self.plan, tcp=True).start()
            dw = self.config.drawwire
            if dw is not None:
                self.drawwire = SimDrawWire(
                    self.robot.drawwire_length, zero=self.robot.zero_drawwire,
                    metres_per_count=dw.metres_per_count, offset_m=dw.offset_m,
                    word_order=WORD_ORDER[dw.word_order], device_id=dw.device_id,
                    rtu=self._rtu, baudrate=dw.baudrate, faults=self.plan).start()
            if self.config.mocap is not None:
                self.mocap = start_mocap(self.robot, self.truth, self.config.mocap, self._seed)
            if self._control:
                self._server = _ControlServer(("127.0.0.1", 0), _ControlHandler)
                self._server.station = self
                threading.Thread(target=self._server.serve_forever, name="sim control",
                                 daemon=True).start()
        except BaseException:
            self.stop()
            raise
        return self

    def _limit(self):
        """The simulated PM's physical limit hit since the last check, as ``(axis, EMCY
        manufacturer bytes)`` for the drives (:meth:`SimulatedAgebot.supervise`)."""
        hit = self.robot.supervise()
        names = SERIAL_LIMITS if self.truth.spec is not None else LIMIT_NAMES
        return None if hit is None else (hit[0], names[hit[1]])

    def stop(self) -> None:
        """Stop every simulated device (idempotent)."""
        if self._server is not None:
            self._server.shutdown()
            self._server.server_close()
            self._server = None
        for dev in (self.mocap, self.drawwire, self.inclinometer, self.canopen):
            if dev is not None:
                try:
                    dev.stop()
                except Exception as e:
                    log.warning("stopping %s: %s", type(dev).__name__, e)
        self.canopen = self.inclinometer = self.drawwire = self.mocap = None
        self._stopped.set()

    def __enter__(self):
        return self.start()

    def __exit__(self, *exc):
        self.stop()

    # -- what clients need -------------------------------------------------------------
    @property
    def endpoints(self) -> dict[str, Any]:
        """The endpoints record of cli.md (plus ``control``, ``robot`` and RTU/TCP extras)."""
        out: dict[str, Any] = {"robot": self.truth.robot, "canopen": self.canopen.endpoint}
        if self.inclinometer is not None:
            out["inclinometer"] = {"port": self.inclinometer.port, "url": self.inclinometer.url,
                                   "baudrate": self.config.inclinometer.baudrate}
        if self.drawwire is not None:
            out["drawwire"] = {"host": self.drawwire.host, "port": self.drawwire.port,
                               "device_id": self.drawwire.device_id,
                               "rtu_port": self.drawwire.rtu_port}
        if self.mocap is not None:
            out["mocap"] = {"host": "127.0.0.1", "port": self.mocap.port}
        if self._server is not None:
            host, port = self._server.server_address[:2]
            out["control"] = {"host": host, "port": port}
        return out

    def command(self, cmd: dict) -> dict:
        """One control command (module docstring); raises ValueError/KeyError/TypeError."""
        if not isinstance(cmd, dict):
            raise TypeError("a command is a JSON object")
        known = {"faults", "clear", "state", "move", "drop_drawwire", "contact", "mocap",
                 "pose_noise"}
        unknown = set(cmd) - known
        if unknown:
            raise KeyError(f"unknown command {sorted(unknown)} (known: {sorted(known)})")
        if cmd.get("clear"):
            self.plan.clear()
        if "faults" in cmd:
            self.plan.update(**cmd["faults"])
        if self.drawwire is not None and ("faults" in cmd or cmd.get("clear")):
            self.drawwire.apply_faults()
        if "move" in cmd:
            try:
                qm = np.asarray(cmd["move"], dtype=float)
            except (TypeError, ValueError):
                qm = np.full(1, np.nan)
            if qm.shape != (len(self.robot.axes),) or not np.all(np.isfinite(qm)):
                raise ValueError(f"move: need {len(self.robot.axes)} actuator values (finite "
                                 f"numbers), not {str(cmd['move'])[:60]}")
            self.robot.move_to(qm)
        if "pose_noise" in cmd:
            self.robot.pose_noise = bool(cmd["pose_noise"])
        if cmd.get("drop_drawwire") and self.drawwire is not None:
            self.drawwire.drop_connections()
        if self.mocap is not None and cmd.get("clear"):
            self.mocap.clear_faults()
        if "mocap" in cmd:
            if self.mocap is None:
                raise ValueError("mocap: this simulated station has no motion capture")
            self.mocap.set_faults(**cmd["mocap"])
        answer: dict[str, Any] = {"ok": True, "faults": self.plan.as_dict()}
        if cmd.get("state"):
            answer.update(qm=self.robot.qm().tolist(), pose=self.robot.ee_pose().tolist(),
                          anchor=self.robot.anchor.tolist(),
                          target_reached=self.robot.target_reached(),
                          drawwire_zero_calls=getattr(self.drawwire, "zero_calls", 0),
                          drawwire_offset=getattr(self.drawwire, "offset_m", None))
        if cmd.get("state") and self.truth.points is not None:
            from drivers.sim.urdf_truth import true_points

            answer["points"] = true_points(self.truth, self.robot.model, self.robot._xi,
                                           self.robot.qm()).tolist()
        if cmd.get("contact"):
            answer["contact"] = self.contact()
        return answer

    def contact(self) -> dict:
        """The true tool tip now and its signed distance to the truth's plane (m)."""
        if self.robot.model.name != "agebot-sm":
            raise ValueError("contact: guided touching is for the agebot-sm")
        X = self.robot.ee_pose()
        out = {"tip": X[:3].tolist(), "phi": float(X[3]), "qm": self.robot.qm().tolist(),
               "distance": None}
        if self.truth.plane is not None:
            out["distance"] = self.robot.plane_residual() / float(np.linalg.norm(self.truth.plane))
        return out

    def wait(self, timeout: float | None = None) -> bool:
        return self._stopped.wait(timeout)


class _ControlServer(socketserver.ThreadingTCPServer):
    daemon_threads = True
    allow_reuse_address = True
    station: SimStation


class _ControlHandler(socketserver.StreamRequestHandler):
    def handle(self) -> None:
        for line in self.rfile:
            if not line.strip():
                continue
            try:
                answer = self.server.station.command(json.loads(line))
            except (ValueError, KeyError, TypeError) as e:   # a bad command: its answer
                answer = {"error": f"{type(e).__name__}: {e}"}
            except Exception as e:  # any failure is an answer, never a dropped connection
                log.exception("control command %r failed", line)
                answer = {"error": f"{type(e).__name__}: {e}"}
            self.wfile.write((json.dumps(answer) + "\n").encode())
            self.wfile.flush()


class SimControl:
    """Client of a running simulator's control port (tests, demos, the headless run)."""

    def __init__(self, host: str, port: int, timeout: float = 10.0):
        self._sock = socket.create_connection((host, int(port)), timeout=timeout)
        self._file = self._sock.makefile("rwb")

    @classmethod
    def from_endpoints(cls, endpoints: dict) -> "SimControl":
        c = endpoints.get("control")
        if not c:
            raise ConfigError("the endpoints give no simulator control port", key="control")
        return cls(c["host"], c["port"])

    def call(self, **command) -> dict:
        self._file.write((json.dumps(command) + "\n").encode())
        self._file.flush()
        line = self._file.readline()
        if not line:
            raise ConnectionError("the simulator closed its control port")
        answer = json.loads(line)
        if "error" in answer:
            raise RuntimeError(f"simulator: {answer['error']}")
        return answer

    def close(self) -> None:
        for f in (self._file, self._sock):
            try:
                f.close()
            except OSError:
                pass

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def write_endpoints(path: str | Path, endpoints: dict) -> None:
    """Write the endpoints JSON atomically (a reader never sees half a file)."""
    write_atomic(Path(path), (json.dumps(endpoints, indent=2) + "\n").encode())


def build(robot: str, truth: str | None = None, config: str | None = None, *,
          seed: int | None = None, pose_noise: bool = False) -> SimStation:
    """A :class:`SimStation` from file names (defaults: the fixtures), not started."""
    c = load_sim_config(robot, config, truth)
    return SimStation(truth_of(robot, truth, c), c, seed=seed, pose_noise=pose_noise)


def truth_of(robot: str, truth: str | None, config: StationConfig | None = None):
    """The simulator's truth of ``robot`` (a built-in name or a robot file): the file
    ``truth`` (default: the built-in's fixture, a robot file's nominal), refused in one
    line where it is of another robot."""
    if is_robot_file(robot):     # a robot file: the truth is of it (default: its nominal)
        spec = config.spec if config is not None and config.spec is not None else None
        if spec is None:
            from drivers.robot_file import load_robot_file

            spec = load_robot_file(robot)
        if hasattr(spec, "base_link"):      # a URDF robot: its truth is a true URDF
            return _urdf_truth_of(robot, spec, truth)
        t = load_truth(truth) if truth else nominal_truth(robot)
        if t.spec is None or t.spec.source["sha256"] != spec.source["sha256"]:
            raise ConfigError(f"the truth file is not of the robot file {robot}"
                              + (f" (it is of {t.robot})" if t.robot else ""),
                              source=t.source, key="robot_file")
        return t
    t = load_truth(truth) if truth else load_truth(default_truth_path(robot))
    if t.robot != robot:
        raise ConfigError(f"the truth file is for {t.robot}, not {robot}", source=t.source,
                          key="robot")
    return t


def _urdf_truth_of(robot: str, spec, truth: str | None) -> SimTruth:
    """The truth file of a URDF robot: needed (what the robot really is, where the room
    is), refused in one line where its robot is another."""
    from drivers.sim.urdf_truth import same_chain

    if not truth:
        raise ConfigError(f"a simulated {robot} needs --truth: a truth file of the URDF robot "
                          "(its true URDF, the motion-capture room, the points on the tool)")
    t = load_truth(truth)
    why = ("it is of " + t.robot if t.robot != "urdf" else same_chain(t.spec, spec))
    if why:
        raise ConfigError(f"the truth file is not of the URDF robot {robot}: {why}",
                          source=t.source, key="urdf")
    return t


def load_sim_config(robot: str, config: str | None = None,
                    truth: str | None = None) -> StationConfig:
    """The simulated station's config: ``config``, else the fixture of a built-in robot
    or the default station of a robot file (:func:`drivers.sim.serial_robot.sim_config`;
    a URDF robot's with its ``truth`` file's motion-capture room)."""
    if config:
        return load_station_config(config)
    if is_robot_file(robot):
        from drivers.robot_file import split_urdf_ref

        t = load_truth(truth) if truth and split_urdf_ref(robot) is not None else None
        return sim_config(robot, t if t is not None and t.robot == "urdf" else None)
    return load_station_config(default_config_path(robot))


def main(args: argparse.Namespace) -> int:
    """``app.py simulate``: start, print endpoints, run until SIGINT/SIGTERM."""
    if args.endpoints is not None:     # before the devices start: never over an input
        from drivers.atomic import check_outputs

        check_outputs((args.endpoints, "the endpoints file (--endpoints)"),
                      inputs=tuple(p for p in (args.truth, args.config,
                                               args.robot if is_robot_file(args.robot)
                                               else None) if p))
    station = build(args.robot, args.truth, args.config, seed=getattr(args, "seed", None),
                    pose_noise=getattr(args, "pose_noise", False))
    stop = threading.Event()
    parent = os.getppid() if getattr(args, "exit_with_parent", False) else None

    def on_signal(signum, frame):
        stop.set()

    old = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        with station:
            ep = station.endpoints
            if args.endpoints:
                try:
                    write_endpoints(args.endpoints, ep)
                except OSError as e:
                    raise ConfigError(f"--endpoints {args.endpoints}: cannot write: "
                                      f"{e.strerror or e}") from None
            print(json.dumps(ep), flush=True)
            print(f"simulated {args.robot} running (truth: {station.truth.source or 'report'}); "
                  f"CANopen socketcand {ep['canopen']['host']}:{ep['canopen']['port']}, "
                  f"inclinometer {ep.get('inclinometer', {}).get('port')}, draw-wire Modbus TCP "
                  f"{ep.get('drawwire', {}).get('port')}; Ctrl-C stops", file=sys.stderr,
                  flush=True)
            while not stop.wait(0.2):
                if parent is not None and os.getppid() != parent:
                    break       # the station that started us died (even by SIGKILL)
    finally:
        for s, h in old.items():
            signal.signal(s, h)
        if args.endpoints:
            Path(args.endpoints).unlink(missing_ok=True)
    return 0


__all__ = ["SimStation", "SimControl", "build", "main", "write_endpoints", "report_truth"]


class SimulatorFailed(StationError, RuntimeError):
    """The simulator process stopped before it started its devices (its one-line reason:
    a truth file of another robot, a bad config, ...)."""


class SimulatorProcess:
    """``app.py simulate`` in a child process: the simulated devices in their own
    process, as at a real station. ``endpoints`` is what it printed; :meth:`stop`
    ends it (SIGTERM, then SIGKILL)."""

    def __init__(self, robot: str, truth: str | None = None, config: str | None = None, *,
                 seed: int | None = None, timeout: float = 20.0, pose_noise: bool = False):
        import subprocess

        self.robot, self.config_path = robot, (Path(config) if config else None)
        self.truth = truth
        from drivers.robot_file import robot_args

        cmd = [sys.executable, str(ROOT / "app.py"), "simulate", *robot_args(robot),
               "--exit-with-parent"]
        if truth:
            cmd += ["--truth", str(truth)]
        if config:
            cmd += ["--config", str(config)]
        if seed is not None:
            cmd += ["--seed", str(seed)]
        if pose_noise:
            cmd += ["--pose-noise"]
        self.proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                     stdin=subprocess.DEVNULL, start_new_session=True)
        try:
            self.endpoints = self._first_line(timeout)
        except BaseException:
            self.stop()
            raise
        self.stderr_tail: list[str] = []
        for stream in (self.proc.stdout, self.proc.stderr):
            threading.Thread(target=self._consume, args=(stream,), daemon=True).start()

    def _first_line(self, timeout: float) -> dict:
        import select

        from drivers.errors import DeviceError

        if not select.select([self.proc.stdout], [], [], timeout)[0]:
            raise DeviceError(f"did not start within {timeout:.0f} s", device="simulator")
        line = self.proc.stdout.readline()
        if not line:
            err = self.proc.stderr.read().decode(errors="replace").strip().splitlines()
            last = err[-1] if err else f"code {self.proc.wait()}"
            raise SimulatorFailed("the simulator did not start: " + last.removeprefix("error: "))
        return json.loads(line)

    @property
    def alive(self) -> bool:
        """False once the simulator's process has ended (killed, crashed)."""
        return self.proc.poll() is None

    def _consume(self, stream) -> None:
        try:
            for line in stream:
                if stream is self.proc.stderr:
                    self.stderr_tail = (self.stderr_tail + [line.decode(errors="replace")])[-20:]
        except (OSError, ValueError):
            pass

    def control(self) -> SimControl:
        return SimControl.from_endpoints(self.endpoints)

    def station_config(self) -> StationConfig:
        """The station config it was started with, its endpoints filled from this simulator."""
        return with_endpoints(load_sim_config(self.robot, self.config_path, self.truth),
                              self.endpoints, source="simulator")

    def stop(self) -> None:
        import subprocess

        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(timeout=5)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.stop()
