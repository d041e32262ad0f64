"""The simulated station in one process (threads): the simulated robot and its devices,
and the commands of the simulator's control port (:class:`SimStation`).

One :class:`~drivers.sim.robot.SimulatedAgebot` (or a robot file's
:class:`~drivers.sim.serial_robot.SimulatedSerial`; true parameters from a truth file)
behind the simulated devices, each speaking its real wire protocol:

* CANopen CiA 402 drives (or CiA 406 encoders) on a socketcand hub (TCP, 127.0.0.1);
* the inclinometer on a pseudo-terminal (and ``socket://`` TCP);
* the draw-wire as a Modbus TCP server (and RTU over a pseudo-terminal);
* the motion capture (QTM's real-time protocol) where the station config has ``[mocap]``.

The station config shapes the devices the way the station will expect them: node ids,
encoder resolution, draw-wire scale, offset and word order. The control port
(:mod:`drivers.sim.control`, JSON lines over TCP) takes these commands, through which
tests and demos inject faults and look at the simulated truth::

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

import logging
import socketserver
import threading
from typing import Any

import numpy as np

from calibration.errors import ConfigError
from drivers.config import StationConfig
from drivers.drawwire import WORD_ORDER
from drivers.sim.cia402_drive import start_canopen_sim
from drivers.sim.control import ControlHandler, ControlServer
from drivers.sim.drawwire_sim import SimDrawWire
from drivers.sim.faults import FaultPlan
from drivers.sim.inclinometer_sim import SimInclinometer
from drivers.sim.mocap_room import start_mocap
from drivers.sim.robot import LIMIT_NAMES, SimulatedAgebot
from drivers.sim.serial_robot import LIMIT_NAMES as SERIAL_LIMITS
from drivers.sim.serial_robot import SimulatedSerial
from drivers.sim.truth import SimTruth

log = logging.getLogger("drivers.sim")


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
                self._server = ControlServer(("127.0.0.1", 0), ControlHandler)
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
