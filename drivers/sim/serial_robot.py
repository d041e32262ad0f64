"""The simulated serial robot of a robot file (docs/robot-files.md).

:class:`SimulatedSerial` is :class:`~drivers.sim.robot.SimulatedAgebot` for any
serial arm: one :class:`~drivers.sim.axis.SimAxis` per joint (driven by one
simulated CiA 402 drive each), the true model of the truth file's robot file,
the draw-wire on the tool origin and a dual-axis inclinometer on the tool. The
noise, the draw-wire's zero and the encoders are the AGEBOT simulator's
(inherited); what differs is the pose, the inclinometer and the limits:

* pose ``X = [x, y, z, roll, pitch, yaw]`` of the tool frame in the base frame;
* the inclinometer reads :func:`calibration.robots.inclinometer.gravity_tilt` of the
  tool's orientation, mounted by the truth's ``inclinometer_mount`` (``Rx Ry``),
  noise channels ``roll``/``pitch`` (``tilt`` where those are not given); yaw 0;
* repeatability (a truth's ``repeatability``; :mod:`drivers.sim.axis`): the links are
  where the motors are plus each move's play (backlash, a random positioning error);
  the kinematics, the sensors and the motion capture see the links, the drives'
  encoders the motors;
* physical limits, checked along every motion (:meth:`SimulatedSerial.supervise`,
  steps of at most :data:`SUPERVISE_STEP` rad or actuator units): a joint beyond
  its robot-file ``limits`` (``JLIM``) or the tool origin below the floor ``z = 0``
  of the base frame (``FLOOR``) stops every axis at the last point inside and
  faults the drive (EMCY 0x8612, manufacturer bytes naming the limit) of the joint
  at its limit, or of the joint that moved most for the floor.

The axes start at :func:`home_qm`: the middle of the limits, or where that puts
the tool below the floor, the first of a fixed sequence of joint values in the
middle of the limits that keeps it :data:`HOME_FLOOR` above.
"""
from __future__ import annotations

import logging
import time
from pathlib import Path

import numpy as np

from calibration.errors import ConfigError
from calibration.robots.agebot_pm import gravity_tilt
from drivers.sim.axis import SimAxis
from drivers.sim.faults import FaultPlan
from drivers.sim.repeatability import axis_play
from drivers.sim.robot import SimulatedAgebot
from drivers.sim.truth import SimTruth

log = logging.getLogger("drivers.sim")

SUPERVISE_STEP = 0.02     # rad (actuator units) between two checks of the limits
HOME_FLOOR = 0.15         # m: the home pose's tool origin at least this far above the floor
LIMIT_NAMES = {"joint limit": b"JLIM", "floor": b"FLOOR"}
VELOCITY, ACCELERATION = 2.0, 10.0   # default axis speed (units/s) and acceleration (/s^2)


def home_qm(model, xi, floor: float = HOME_FLOOR) -> np.ndarray:
    """Start actuator values (module docstring); ConfigError where none keeps the tool up."""
    lo, hi = model.limits[:, 0], model.limits[:, 1]
    mid = (lo + hi) / 2
    rng = np.random.default_rng(0)
    cand = np.vstack([mid, rng.uniform(mid - 0.3 * (hi - lo), mid + 0.3 * (hi - lo),
                                       size=(500, len(mid)))])
    z = model.fk(cand, xi)[:, 2]
    ok = np.flatnonzero(z >= floor)
    if not ok.size:
        raise ConfigError(f"no start pose of {model.name} keeps its tool above the floor z = 0 "
                          "of the base frame: is the base frame's z axis up?", key="robot_file")
    return cand[ok[0]].copy()


class SimulatedSerial(SimulatedAgebot):
    """A robot file's robot behind the simulated devices (module docstring). Arguments
    as :class:`SimulatedAgebot`'s; ``home`` is actuator values here; ``qm_range`` the
    station config's ``[envelope]`` (within the robot file's limits)."""

    def __init__(self, truth: SimTruth, *, faults: FaultPlan | None = None,
                 seed: int | None = None, home=None, velocity=None, acceleration=None,
                 clock=time.monotonic, pose_noise: bool = False, qm_range=None):
        if truth.spec is None:
            raise ConfigError("the truth file names no robot file", source=truth.source,
                              key="robot_file")
        self._hold(truth, truth.model(), faults, seed, pose_noise)
        n = self.model.n_actuators
        lim = np.asarray(self.model.limits, dtype=float)
        if qm_range is not None:     # the station config's [envelope], within the limits
            r = np.asarray(qm_range, dtype=float)
            lim = np.column_stack([np.maximum(lim[:, 0], r[:, 0]), np.minimum(lim[:, 1], r[:, 1])])
        self.qm_range = lim
        self.home_qm = (home_qm(self.model, self._xi) if home is None
                        else np.asarray(home, dtype=float))
        self.home_pose = self.model.fk(self.home_qm, self._xi)[0]
        vel = np.broadcast_to(VELOCITY if velocity is None else velocity, (n,))
        acc = np.broadcast_to(ACCELERATION if acceleration is None else acceleration, (n,))
        play = axis_play(truth, self.model, self._xi, self._seed)
        self.axes = tuple(SimAxis(float(p), float(v), float(a), clock=clock, **kw)
                          for p, v, a, kw in zip(self.home_qm, vel, acc, play))
        self._checked = (clock(), self.home_qm.copy(), False)   # (t, qm, found inside)
        self._anchor = self.ee_position()

    # -- state -----------------------------------------------------------------------------
    def frame(self) -> np.ndarray:
        """The true tool frame ``T (4, 4)`` in the base frame now."""
        return self.model.frames(self.qm(), self._xi)[0]

    def ee_pose(self) -> np.ndarray:
        """True ``[x, y, z, roll, pitch, yaw]`` of the tool frame now (m, rad)."""
        return self.model.fk(self.qm(), self._xi)[0]

    def ee_position(self) -> np.ndarray:
        return self.frame()[:3, 3].copy()

    def move_to_pose(self, X, elbow: int = 1) -> np.ndarray:
        """Command the tool origin to ``X[:3]`` (numeric IK at the true parameters from
        the axes' targets)."""
        qm = self.model.move_to([a.target for a in self.axes], np.asarray(X)[:3], self._xi)
        self.move_to(qm)
        return qm

    def supervise(self) -> tuple[int, str] | None:
        """Walk the motion since the last call (module docstring); at a limit, stop every
        axis at the last point inside and return ``(axis, kind)``, else None."""
        with self._lock:
            t0, q0, inside = self._checked
            t1 = self.axes[0].now()
            q1 = np.array([a.position_at(t1) for a in self.axes])
            t_end = min(t1, max(max(a.end_time() for a in self.axes), t0))
            if inside and t_end <= t0:
                # every axis ended its move by the last check, which found that pose
                # inside (the station polls the statusword at rest): nothing to walk
                self._checked = (t1, q1, True)
                return None
            # (the path's length, not the net displacement: a move out past a limit
            # and back between two checks is walked too)
            path = max(a.travel(t0, t_end) for a in self.axes)
            n = max(1, 2 * int(np.ceil(path / SUPERVISE_STEP)))
            ts = np.linspace(t0, t_end, n + 1)[1:]
            Q = np.array([[a.position_at(t) for a in self.axes] for t in ts])
            z = self.model.frames(Q, self._xi)[:, 2, 3]
            lo, hi = self.qm_range[:, 0], self.qm_range[:, 1]
            out = (Q < lo - 1e-9) | (Q > hi + 1e-9)
            bad = np.flatnonzero(out.any(axis=1) | (z < 0.0))
            if not bad.size:
                self._checked = (t1, q1, True)
                return None
            k = int(bad[0])
            if out[k].any():
                hit = (int(np.argmax(out[k])), "joint limit")
            else:
                hit = (int(np.argmax(np.abs(Q[k] - q0))), "floor")
            t_ok = ts[k] - (t_end - t0) / n
            for a in self.axes:
                a.stop_at(t_ok)
            self._checked = (self.axes[0].now(), self.qm(), False)
            log.warning("simulated %s: %s hit at qm %s", self.model.name, hit[1],
                        np.round(Q[k], 3).tolist())
            return hit

    # -- sensors ----------------------------------------------------------------------------
    def inclinometer_angles(self) -> tuple[float, float, float]:
        """Noise-free ``(roll, pitch, 0)`` of the tool inclinometer, rad."""
        roll, pitch = gravity_tilt(self.frame()[:3, :3], self.truth.inclinometer_mount)
        return roll, pitch, 0.0

    def inclinometer_angles_deg(self) -> tuple[float, float, float]:
        roll, pitch, yaw = self.inclinometer_angles()
        ch = {c: (c if self.truth.sigma(c) else "tilt") for c in ("roll", "pitch")}
        roll += self._noise(ch["roll"], key="roll")
        pitch += self._noise(ch["pitch"], key="pitch") + np.radians(
            self.glitch(self.faults.glitch_tilt_deg))
        return tuple(float(np.degrees((a + np.pi) % (2 * np.pi) - np.pi))
                     for a in (roll, pitch, yaw))

    def plane_residual(self) -> float:
        raise ConfigError("guided touching is not simulated for robot files",
                          source=self.truth.source)


# -- the station config of a simulated robot file ------------------------------------------
def is_robot_file(robot: str) -> bool:
    """True where ``robot`` names a robot file (a path), not a built-in robot."""
    from calibration.robots import ROBOTS

    return robot not in ROBOTS


#: the simulated nodes and their socketcand server share the host with the station (the
#: wizard drawing, the CI's two cores), which delays their heartbeats and SDO answers by
#: tenths of a second; a real bus keeps the example's 0.5 s for both
#: (fixtures/stations/example-real.toml)
SIM_HEARTBEAT_TIMEOUT = 2.0
SIM_SDO_TIMEOUT = 2.0


def sim_config_data(spec, *, velocity: float = VELOCITY,
                    acceleration: float = ACCELERATION, truth: SimTruth | None = None) -> dict:
    """The default simulated station of a robot file, as a station config document:
    drives at node ids 1..n (2^17 increments per actuator unit), the draw-wire on
    Modbus TCP, a dual-axis inclinometer on the tool mapped to ``roll`` and ``pitch``;
    a URDF robot's ``truth`` with points on the tool adds the motion capture of its room
    (:func:`drivers.sim.mocap_room.room_section`)."""
    n = len(spec.joints)
    extra = {}
    if truth is not None and truth.points is not None:
        from drivers.sim.mocap_room import room_section

        extra["mocap"] = room_section(truth)
    return extra | {
        "robot": spec.name,
        "canopen": {"mode": "cia402", "interface": "socketcand", "channel": "can0",
                    "host": "@endpoints", "port": "@endpoints", "nodes": list(range(1, n + 1)),
                    "increments_per_unit": [131072] * n, "profile_velocity": [velocity] * n,
                    "profile_acceleration": [acceleration] * n, "sdo_timeout": SIM_SDO_TIMEOUT,
                    "move_timeout": 30.0, "heartbeat_period": 0.1,
                    "heartbeat_timeout": SIM_HEARTBEAT_TIMEOUT, "sync_period": 0.02},
        "inclinometer": {"port": "@endpoints", "baudrate": 115200, "timeout": 1.0,
                         "axes": {"roll": {"raw": "roll"}, "pitch": {"raw": "pitch"}}},
        "drawwire": {"mode": "tcp", "host": "@endpoints", "port": "@endpoints", "device_id": 1,
                     "word_order": "high-first", "metres_per_count": 1e-6, "offset_m": 0.0,
                     "timeout": 1.0},
        "snapshot": {"samples": 5, "period": 0.02, "settle": 0.05, "timeout": 1.0,
                     "std_limits": {"qm": 0.01, "roll": 2e-3, "pitch": 2e-3, "distance": 2e-4},
                     "drift_limits": {"qm": 0.01, "roll": 2e-3, "pitch": 2e-3,
                                      "distance": 2e-4}},
    }


def sim_config(robot_file: str | Path, truth: SimTruth | None = None):
    """:func:`sim_config_data` of a robot file (a URDF robot, with its ``truth``) as a
    :class:`~drivers.config.StationConfig`."""
    from drivers.config import parse_station_config
    from drivers.robot_file import load_robot_file

    spec = load_robot_file(robot_file)
    return parse_station_config(sim_config_data(spec, truth=truth),
                                f"default station of {robot_file}", spec=spec)


def nominal_truth(robot_file: str | Path) -> SimTruth:
    """A noise-free truth equal to the robot file's nominal (no ``--truth`` given)."""
    from drivers.config_reader import frozen_map
    from drivers.robot_file import load_robot_file

    spec = load_robot_file(robot_file)
    model = SimTruth(robot=spec.name, parameters=frozen_map({}), spec=spec).model()
    return SimTruth(robot=spec.name, parameters=frozen_map(model.as_dict(model.nominal)),
                    spec=spec, robot_file=str(robot_file))


def draw_serial_truth(robot_file: str | Path, rng: np.random.Generator, *,
                      length: float = 0.003, angle: float = 0.005, noise=None,
                      seed: int | None = None, inclinometer_mount=(0.0, 0.0)) -> SimTruth:
    """A robot of a robot file that is not its nominal: every free parameter drawn
    uniformly around the file's value, lengths by ``+-length`` m, angles and offsets by
    ``+-angle`` rad (gear ratios relative by ``+-angle``); the file's ``fixed`` ones held
    (the calibration holds them too)."""
    from drivers.config_reader import frozen_map
    from drivers.robot_file import load_robot_file

    spec = load_robot_file(robot_file)
    model = SimTruth(robot=spec.name, parameters=frozen_map({}), spec=spec).model()
    angles = {"theta", "alpha", "beta", "gamma"}
    params = {}
    for name, v in zip(model.param_names, model.nominal):
        base = name.split("_")[-1].rstrip("0123456789")
        if name in model.fixed:
            params[name] = float(v)
        elif name[0] == "k" and name[1:].isdigit():
            params[name] = float(v * (1 + rng.uniform(-angle, angle)))
        elif name.endswith("_off") or base in angles:
            params[name] = float(v + rng.uniform(-angle, angle))
        else:
            params[name] = float(v + rng.uniform(-length, length))
    return SimTruth(robot=spec.name, parameters=frozen_map(params),
                    noise=frozen_map(dict(noise or {})), seed=seed,
                    inclinometer_mount=tuple(inclinometer_mount), spec=spec,
                    robot_file=str(Path(robot_file).resolve()))
