"""The simulated AGEBOT behind the simulated devices (its conventions are stated below; the
real devices it stands in for: docs/real-station.md).

:class:`SimulatedAgebot` holds the true parameters (a :class:`~drivers.sim.truth.SimTruth`)
and one :class:`~drivers.sim.axis.SimAxis` per actuator; the simulated drives move
the axes, and every sensor value is computed from the axes' current positions
with the robot model at the true parameters, plus Gaussian noise of the truth
file's standard deviations. Thread-safe: the device simulators call it from
their own threads.

Inclinometer conventions (the calibration's measurement model builds on these):

* **SM** -- the sensor sits on the last link, whose angle ``phi`` (from ``x_b``
  in the vertical arm plane) it reads as its **pitch**; roll reads 0 and yaw 0,
  each plus noise. Angles are wrapped to ``[-180, 180)`` degrees.
* **PM** -- a physical dual-axis inclinometer on the platform measures the
  direction of gravity in its own frame. With the platform orientation
  ``R = Rx(alpha) Ry(beta) Rz(gamma)`` (``rot_xyz``) and the sensor's mounting
  rotation ``R_mount = Rx(mx) Ry(my)`` on the platform (truth file, default 0)::

      g_s   = R_mount^T R^T (0, 0, -1)              # unit gravity, sensor frame
      roll  = atan2(-g_y, -g_z)                     # rotation about the sensor x axis
      pitch = atan2( g_x, sqrt(g_y^2 + g_z^2))      # rotation about the sensor y axis

  so that ``R = Rx(a)`` reads ``roll = a, pitch = 0`` and ``R = Ry(b)`` reads
  ``roll = 0, pitch = b`` (|a|, |b| < 90 deg); in general the yaw-pitch-roll
  orientation ``R = Rz(c) Ry(b) Rx(a)`` reads exactly ``(a, b)`` for any heading
  ``c`` (a rotation about gravity changes nothing). The report's
  ``Rx(alpha) Ry(beta) Rz(gamma)`` couples them: ``gamma`` turns the sensor about
  its own z and so mixes roll and pitch. Yaw is the heading ``c`` of that same
  yaw-pitch-roll decomposition of ``R R_mount`` (an AHRS's fused heading,
  relative to the home pose; :func:`sensor_heading`), so that roll, pitch and yaw
  together give the full orientation (:func:`euler_from_ypr`, for pm-fk). On the
  SM yaw reads 0.
  :func:`gravity_tilt` (:mod:`calibration.robots.agebot_pm`) is this function, pure
  and vectorized; the calibration model uses the same one.

Physical limits (PM): the wrist cannot go where it cannot be built. Whenever a
simulated drive is asked for its state (:meth:`SimulatedAgebot.supervise`), the
motion since the last check is walked in steps of at most :data:`SUPERVISE_STEP`
actuator units; at the first point beyond the envelope -- a slider outside its
stroke (``qm_range``, the station config's ``[envelope]``), a passive joint outside
:data:`calibration.robots.agebot_pm.PASSIVE_RANGE`, a rod that cannot reach its
platform point -- every axis stops at the last point inside, and the drive of
that rod goes to FAULT with EMCY 0x8612 (reference limit) whose manufacturer
bytes name what was hit (:data:`LIMIT_NAMES`: ``STRK`` stroke, ``SLDJ`` slider
joint, ``PLTJ`` platform joint, ``CTRJ`` centre joint, ``REACH`` a rod cannot reach).

Physical limits (SM): each axis travels the true robot's joint range (rail
+-2 m, joints +-170 deg) through the true transmission (:meth:`physical_limits`);
a set-point beyond is refused by the drive: FAULT, EMCY 0x8612 with manufacturer
bytes ``TRVL``, the axis stays where it is.

The draw-wire reads ``|p - anchor|`` (m) where ``p`` is the end-effector
position (SM: ``X[:3]``; PM: the fixed platform centre ``(0, 0, v)``) and the
anchor is the true ``p`` when :meth:`SimulatedAgebot.zero_drawwire` was called
(the operator attaches the cable at the reference point and zeroes the sensor);
before the first zero the anchor is the home position.
"""
from __future__ import annotations

import hashlib
import logging
import math
import threading
import time

import numpy as np

from calibration.errors import CalibrationError, ConfigError, UnreachablePose
from calibration.robots import get_robot
from calibration.robots.agebot_pm import (beyond_envelope, envelope_hit,
                                          gravity_tilt,  # noqa: F401 (re-exported: the one tilt convention)
                                          rot_xyz, sensor_heading)
from drivers.sim.axis import SimAxis
from drivers.sim.faults import FaultPlan
from drivers.sim.repeatability import axis_play
from drivers.sim.truth import SimTruth

log = logging.getLogger("drivers.sim")

HOME = {"agebot-sm": (1.2, 1.4, 0.0, 0.0), "agebot-pm": (0.0, 0.0, 0.0)}
# default axis speeds (actuator units/s) and accelerations (units/s^2)
VELOCITY = {"agebot-sm": (50.0, 200.0, 200.0, 200.0), "agebot-pm": (3000.0,) * 3}
ACCELERATION = {"agebot-sm": (400.0, 2000.0, 2000.0, 2000.0), "agebot-pm": (30000.0,) * 3}
SUPERVISE_STEP = 20.0      # actuator units between two checks of the PM's envelope
#: a move's velocity and acceleration within this relative difference of the axis's
#: defaults is at the configured profile (the drives take them in whole increments)
PROFILE_RTOL = 1e-3
#: actuator units: the arm is at the fault plan's ``glitch_qm`` where every axis's target
#: is this close (the drives take targets in whole increments)
GLITCH_QM = 1e-4
#: the largest change of orientation (rad) between two points of a walk taken at once
#: (:meth:`SimulatedAgebot._walk_at_once`); larger, the assembly may have flipped
WALK_JUMP = 0.1
#: EMCY manufacturer bytes (ASCII) naming the limit a PM drive faulted on
LIMIT_NAMES = {"stroke": b"STRK", "slider joint": b"SLDJ", "platform joint": b"PLTJ",
               "centre joint": b"CTRJ", "reach": b"REACH"}


def pose_tilt(X, mount=(0.0, 0.0)):
    """:func:`gravity_tilt` of PM orientations ``X = [alpha, beta, gamma]`` ((3,) or (m, 3))."""
    X = np.asarray(X, dtype=float)
    roll, pitch = gravity_tilt(rot_xyz(X), mount)
    return (float(roll[0]), float(pitch[0])) if X.ndim == 1 else (roll, pitch)


def _wrap_deg(a: float) -> float:
    return (a + 180.0) % 360.0 - 180.0


class SimulatedAgebot:
    """One simulated AGEBOT (SM or PM).

    truth:   the true robot (parameters, noise std per channel, seed, PM mount).
    faults:  the fault plan shared with the device simulators (held here for them).
    seed:    seed of the noise generator (default: ``truth.seed``).
    home:    start pose X (default SM ``(1.2, 1.4, 0, 0)``, PM ``(0, 0, 0)``); the axes
             start at its actuator values by IK at the true parameters.
    velocity, acceleration: per-axis defaults of the axes (actuator units/s, /s^2).
    clock:   time source of the axes (tests may pass a fake one).
    pose_noise: the noise of a reading taken at rest is a function of the seed, the
             channel, the axes' targets and how the axes came there (:meth:`approach`):
             the same pose reached at the configured motion profile reads the same
             values, whenever and however often it is visited (for tests that compare a
             resumed session with an uninterrupted one reading by reading), and reached
             with another profile (the station's slower approach when it measures a
             reading again) a draw of its own, as a real sensor's next reading would be;
             readings while moving keep drawing from the generator.
    qm_range: PM slider stroke ``(3, 2)`` (actuator units), or None (no stroke limit).
    """

    def __init__(self, truth: SimTruth, *, faults: FaultPlan | None = None,
                 seed: int | None = None, home=None, velocity=None, acceleration=None,
                 clock=time.monotonic, pose_noise: bool = False, qm_range=None):
        self._hold(truth, get_robot(truth.robot), faults, seed, pose_noise)
        self.home_pose = np.array(HOME[truth.robot] if home is None else home, dtype=float)
        try:
            self.home_qm = np.asarray(self.model.ik(self.home_pose, self._xi), dtype=float)
        except UnreachablePose as e:
            raise ConfigError(f"the home pose {self.home_pose.tolist()} is unreachable with "
                              f"these parameters: {e}", source=truth.source,
                              key="parameters") from e
        n = self.model.n_actuators
        vel = np.broadcast_to(VELOCITY[truth.robot] if velocity is None else velocity, (n,))
        acc = np.broadcast_to(ACCELERATION[truth.robot] if acceleration is None
                              else acceleration, (n,))
        self.qm_limits = self.physical_limits()
        play = axis_play(truth, self.model, self._xi, self._seed)
        self.axes = tuple(SimAxis(float(p), float(v), float(a), clock=clock, limits=lim,
                                  name=f"axis {i + 1}", **play[i])
                          for i, (p, v, a, lim) in enumerate(zip(self.home_qm, vel, acc,
                                                                 self.qm_limits)))
        self._last_pose = self.home_pose.copy()  # PM: keeps the FK's assembly mode
        self.qm_range = None if qm_range is None else np.asarray(qm_range, dtype=float)
        self._checked = (clock(), self.home_qm.copy(), self.home_pose.copy())
        self._anchor = self.ee_position()

    def physical_limits(self) -> list[tuple[float, float] | None]:
        """Per axis, the actuator range the true robot can travel (actuator units): the
        model's joint limits (SM: rail +-2 m, joints +-170 deg) through the true
        transmission ``Q = K*Qm + Q_off``; None where the model has none."""
        lim = getattr(self.model, "joint_limits", None)
        if lim is None:
            return [None] * self.model.n_actuators
        names = self.model.param_names
        out = []
        for i, (lo, hi) in enumerate(lim):
            k = self._xi[names.index(f"k{i + 1}")]
            off = self._xi[names.index(f"q{i + 1}_off")]
            a, b = (lo - off) / k, (hi - off) / k
            out.append((min(a, b), max(a, b)))
        return out

    def _hold(self, truth: SimTruth, model, faults, seed, pose_noise: bool) -> None:
        """The truth, its model and parameters, the fault plan and the noise generator
        (the constructor's part that every simulated robot shares)."""
        self.truth, self.model = truth, model
        self._xi = truth.xi()
        self.faults = faults if faults is not None else FaultPlan()
        self._seed = truth.seed if seed is None else seed
        self._rng = np.random.default_rng(self._seed)
        self.pose_noise = pose_noise
        self._lock = threading.RLock()

    # -- state -----------------------------------------------------------------------------
    @property
    def xi(self) -> np.ndarray:
        """The true parameter vector (a copy)."""
        return self._xi.copy()

    def qm(self) -> np.ndarray:
        """True actuator values ``(n,)`` now (actuator units): the links' (the encoders
        read the motors': they differ by the truth's repeatability, :mod:`drivers.sim.axis`)."""
        return np.array([a.link_position() for a in self.axes])

    def ee_pose(self, ago: float = 0.0) -> np.ndarray:
        """True generalized coordinates now (``ago`` s before now): SM ``[x, y, z, phi]``
        (m, rad), PM ``[alpha, beta, gamma]`` (rad)."""
        if ago > 0.0:
            t = self.axes[0].now() - ago
            qm = np.array([a.link_position(t) for a in self.axes])
        else:
            qm = self.qm()
        if self.model.name == "agebot-sm":
            return self.model.fk(qm, self._xi)[0]
        with self._lock:
            try:
                self._last_pose = self.model.fk(qm, self._xi, guess=self._last_pose)[0]
            except CalibrationError as e:  # cannot happen on a real robot: keep the last pose
                log.warning("simulated PM: %s; keeping the last pose", e)
            return self._last_pose.copy()

    def ee_position(self) -> np.ndarray:
        """End-effector point ``(3,)`` in the base frame, m (PM: the platform centre)."""
        if self.model.name == "agebot-sm":
            return self.ee_pose()[:3]
        return np.array([0.0, 0.0, self._xi[self.model.index("v")]])

    def _noise(self, channel: str, size=None, key: str = ""):
        sigma = self.truth.sigma(channel)
        if sigma == 0.0:
            return 0.0 if size is None else np.zeros(size)
        if self.pose_noise and self.target_reached():
            pose = tuple(round(a.target, 9) for a in self.axes)
            how = self.approach()
            digest = hashlib.blake2b(repr((self._seed, channel, key, pose)
                                          + (() if how is None else (how,))).encode(),
                                     digest_size=8).digest()
            return np.random.default_rng(int.from_bytes(digest, "little")).normal(0.0, sigma,
                                                                                  size)
        with self._lock:
            return self._rng.normal(0.0, sigma, size)

    def approach(self) -> tuple | None:
        """How the axes came to where they are: None at the configured motion profile
        (every axis's last move at its default velocity and acceleration, to the
        rounding of the drives' integer increments), else each axis's velocity and
        acceleration as fractions of its defaults (rounded to 1e-3)."""
        ratios = [r for a in self.axes for r in a.profile_ratio()]
        if all(abs(r - 1.0) <= PROFILE_RTOL for r in ratios):
            return None
        return tuple(round(r, 3) for r in ratios)

    # -- motion ------------------------------------------------------------------------------
    def move_to(self, qm, velocity=None, acceleration=None) -> None:
        """Command every axis to ``qm (n,)`` (what the simulated drives do per axis)."""
        for axis, target in zip(self.axes, np.asarray(qm, dtype=float)):
            axis.command(float(target), velocity, acceleration)

    def move_to_pose(self, X, elbow: int = 1) -> np.ndarray:
        """Command the pose ``X`` (IK at the true parameters); returns the target ``qm``."""
        qm = (self.model.ik(X, self._xi, elbow=elbow) if self.model.name == "agebot-sm"
              else self.model.ik(X, self._xi))
        self.move_to(qm)
        return qm

    def supervise(self) -> tuple[int, str] | None:
        """PM: walk the motion since the last call (module docstring); at a limit, stop
        every axis at the last point inside and return ``(axis, kind)`` (0-based axis,
        kind a key of :data:`LIMIT_NAMES`), else None. The SM: always None."""
        if self.model.name != "agebot-pm":
            return None
        with self._lock:
            t0, q0, X = self._checked
            t1 = self.axes[0].now()
            q1 = np.array([a.position_at(t1) for a in self.axes])
            t_end = min(t1, max(max(a.end_time() for a in self.axes), t0))
            # the path's length, not the net displacement (a move out past a limit and
            # back between two checks is walked too)
            path = max(a.travel(t0, t_end) for a in self.axes)
            if path < 1e-9:     # no motion: the pose checked last holds
                self._checked = (t1, q1, X)
                return None
            # displacement over time is not uniform (acceleration): twice the steps
            n = max(1, 2 * int(np.ceil(path / SUPERVISE_STEP)))
            ts = np.linspace(t0, t_end, n + 1)[1:]
            Q = np.array([[a.position_at(t) for a in self.axes] for t in ts])
            inside = self._walk_at_once(Q, X)
            if inside is not None:
                self._checked = (t1, q1, inside[-1])
                return None
            for t, q in zip(ts, Q):     # point by point: the first beyond, named
                try:
                    Xt = self.model.fk(np.atleast_2d(q), self._xi, guess=X)[0]
                    hit = envelope_hit(Xt, self._xi, q, self.qm_range)
                except CalibrationError:
                    moved = np.abs(q - q0)
                    hit = ("reach", int(np.argmax(moved)), "")
                if hit is not None and hit[0] == "centre joint":   # the slider that drove it
                    hit = (hit[0], int(np.argmax(np.abs(q - q0))), hit[2])
                if hit is not None:
                    t_ok = t - (t_end - t0) / n
                    for a in self.axes:
                        a.stop_at(t_ok)
                    self._checked = (self.axes[0].now(), self.qm(), X)
                    log.warning("simulated PM: %s hit at qm %s", hit[0], np.round(q, 1).tolist())
                    return hit[1], hit[0]
                X = Xt
            self._checked = (t1, q1, X)
        return None

    def _walk_at_once(self, Q, X) -> np.ndarray | None:
        """The poses ``(n, 3)`` at the actuator values ``Q (n, 3)`` of a walk from the
        pose ``X``, solved together, where every one is inside the envelope and the
        walk follows on from ``X`` (no step above :data:`WALK_JUMP`: the assembly kept);
        else None, and :meth:`supervise` walks point by point (each from the last),
        which finds and names the first point beyond. A drive's state is read over
        SDO and answered after this walk: point by point a 200-400 unit move took
        30-45 ms of the simulator's CPU, a share of the station's 0.5 s SDO timeout
        that grows on a loaded machine; at once about a tenth of that."""
        try:
            Xs = self.model.fk(Q, self._xi, guess=X)
        except CalibrationError:
            return None
        if np.max(np.abs(np.diff(np.vstack([X, Xs]), axis=0))) > WALK_JUMP:
            return None
        return None if beyond_envelope(Xs, self._xi, Q, self.qm_range).any() else Xs

    def target_reached(self) -> bool:
        return all(a.target_reached() for a in self.axes)

    def wait(self, timeout: float = 30.0, poll: float = 0.005) -> bool:
        """Block until every axis reached its target (True) or ``timeout`` s passed (False)."""
        end = time.monotonic() + timeout
        while not self.target_reached():
            if time.monotonic() > end:
                return False
            time.sleep(poll)
        return True

    # -- sensors ----------------------------------------------------------------------------
    def encoder_increments(self, i: int, resolution: float) -> int:
        """Encoder value of axis ``i`` (0-based): ``round((qm_i + noise) * resolution)``;
        ``resolution`` in increments per actuator unit, noise channel ``qm``."""
        return int(round((self.axes[i].position() + self._noise("qm", key=str(i)))
                         * resolution))

    def inclinometer_angles(self) -> tuple[float, float, float]:
        """Noise-free ``(roll, pitch, yaw)`` in rad (module docstring), of the pose
        ``faults.inclinometer_lag_s`` ago."""
        X = self.ee_pose(self.faults.inclinometer_lag_s)
        if self.model.name == "agebot-sm":
            return 0.0, float(X[3]), 0.0
        roll, pitch = pose_tilt(X, self.truth.inclinometer_mount)
        return roll, pitch, sensor_heading(rot_xyz(X)[0], self.truth.inclinometer_mount)

    def inclinometer_angles_deg(self) -> tuple[float, float, float]:
        """``(roll, pitch, yaw)`` in degrees as the sensor reports them, with noise
        (SM: pitch ``tilt``, roll ``roll``; PM: ``roll``, ``pitch``), wrapped to [-180, 180)."""
        roll, pitch, yaw = self.inclinometer_angles()
        sm = self.model.name == "agebot-sm"
        roll += self._noise("roll")
        pitch += self._noise("tilt" if sm else "pitch") + math.radians(
            self.glitch(self.faults.glitch_tilt_deg))
        if not sm:
            yaw += self._noise("yaw")
        return tuple(_wrap_deg(math.degrees(a)) for a in (roll, pitch, yaw))

    def zero_drawwire(self) -> None:
        """The draw-wire's zero command: the anchor becomes the end effector's true
        position now, so the next readings are ~0."""
        p = self.ee_position()
        with self._lock:
            self._anchor = p

    @property
    def anchor(self) -> np.ndarray:
        """Draw-wire anchor ``(3,)`` in the base frame, m."""
        with self._lock:
            return self._anchor.copy()

    def drawwire_length(self) -> float:
        """Cable length from the anchor, m: ``|p - anchor| + noise('distance')`` (and a
        disturbance: :meth:`glitch`)."""
        d = float(np.linalg.norm(self.ee_position() - self.anchor))
        return d + float(self._noise("distance")) + self.glitch(self.faults.glitch_distance_m)

    def glitch(self, offset: float) -> float:
        """``offset`` while the arm rests at the fault plan's ``glitch_qm`` reached at the
        configured profile (:meth:`approach`; any way with ``glitch_persists``), else 0:
        a reading disturbed at one pose."""
        f = self.faults
        at = f.glitch_qm
        if not offset or len(at) != len(self.axes) or not self.target_reached() \
                or not (f.glitch_persists or self.approach() is None):
            return 0.0
        near = all(abs(a.target - q) <= GLITCH_QM for a, q in zip(self.axes, at))
        return float(offset) if near else 0.0

    def plane_residual(self) -> float:
        """``a x + b y + c z + 1`` of the truth's sm-plane plane at the end effector
        (0 when it touches the plane); ConfigError if the truth has no plane."""
        if self.truth.plane is None:
            raise ConfigError("the truth file gives no plane (plane_a, plane_b, plane_c)",
                              source=self.truth.source, key="parameters.plane_a")
        return float(np.dot(self.truth.plane, self.ee_position()) + 1.0)
