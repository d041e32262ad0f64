"""One simulated actuator axis: position in actuator units, trapezoidal moves.

The simulated drives (CiA 402) command it; the simulated robot reads its
position to compute every sensor value. Time is ``time.monotonic()``.

Repeatability (off unless a truth file's ``repeatability`` asks for it,
:mod:`drivers.sim.truth`): between the motor, whose encoder the drive reads
(:meth:`SimAxis.position`), and the link the robot's kinematics sees
(:meth:`SimAxis.link_position`) there is a *play*, set anew by each move that
goes somewhere: ``-direction * backlash / 2`` (the link trails the motor by half
the backlash, so a position approached from above and from below differs by the
backlash) plus a random positioning error ``N(0, positioning)`` (the gear train's
friction and elasticity, the servo's settling), drawn from the axis's own
generator. The encoder does not see the play. Both 0: the link is the motor.
"""
from __future__ import annotations

import itertools
import math
import threading
import time

#: s of superseded moves an axis remembers (a lagging sensor's frames show where it was
#: then; faults.MAX_DELAY_S bounds the lag)
HISTORY_S = 60.0


class AxisLimit(ValueError):
    """A commanded target outside the axis's physical travel range."""


class SimAxis:
    """A position-controlled axis with finite speed and acceleration.

    position:     start position (actuator units).
    velocity:     default profile velocity (units/s).
    acceleration: default profile acceleration (units/s^2).
    limits:       ``(lo, hi)`` physical travel range (actuator units), or None; a target
                  outside it is refused (:class:`AxisLimit`) and the axis stays where it is.
    name:         what the axis moves, for messages (e.g. ``"rail (axis 1)"``).
    backlash, positioning: the play between motor and link (module docstring; actuator
                  units, the whole backlash and the std of the random error per move);
                  ``rng`` a numpy Generator for the latter (needed where it is not 0).
    """

    def __init__(self, position: float = 0.0, velocity: float = 2000.0,
                 acceleration: float = 8000.0, clock=time.monotonic, *,
                 limits: tuple[float, float] | None = None, name: str = "axis",
                 backlash: float = 0.0, positioning: float = 0.0, rng=None):
        self.limits = None if limits is None else (float(limits[0]), float(limits[1]))
        self.name = name
        self.backlash, self.positioning = float(backlash), float(positioning)
        if self.positioning and rng is None:
            raise ValueError(f"{name}: a positioning error needs a random generator (rng)")
        self._rng = rng
        self.play = 0.0          # link minus motor position (module docstring)
        self._clock = clock
        self._lock = threading.Lock()
        self._start = float(position)
        self._target = float(position)
        self._t0 = clock()
        self.velocity = float(velocity)
        self.acceleration = float(acceleration)
        self._v = self.velocity
        self._a = self.acceleration
        self._past: list[tuple] = []     # superseded moves (t0, start, target, v, a), oldest first

    def command(self, target: float, velocity: float | None = None,
                acceleration: float | None = None) -> None:
        """Start a move from wherever the axis is now to ``target``; :class:`AxisLimit`
        (and no motion) where ``target`` is outside :attr:`limits`."""
        if self.limits is not None and not self.limits[0] <= target <= self.limits[1]:
            raise AxisLimit(f"{self.name}: target {target:.6g} is outside its travel range "
                            f"[{self.limits[0]:.6g}, {self.limits[1]:.6g}]")
        with self._lock:
            now = self._clock()
            start = self._position_at(now)
            self._supersede(now)
            if float(target) != start and (self.backlash or self.positioning):
                direction = 1.0 if float(target) > start else -1.0
                self.play = -direction * self.backlash / 2 + (
                    float(self._rng.normal(0.0, self.positioning)) if self.positioning else 0.0)
            self._start = start
            self._target = float(target)
            self._t0 = now
            self._v = abs(float(velocity)) if velocity else self.velocity
            self._a = abs(float(acceleration)) if acceleration else self.acceleration

    def stop_at(self, t: float) -> None:
        """Stop where the axis was at time ``t`` (a limit hit then): it stays there."""
        with self._lock:
            here, now = self._position_at(t), self._clock()
            self._supersede(now)
            self._start = self._target = here
            self._t0 = now

    def position_at(self, t: float) -> float:
        """Position at time ``t`` (the clock's time) of the move under way."""
        with self._lock:
            return self._position_at(t)

    def now(self) -> float:
        return self._clock()

    def travel(self, ta: float, tb: float) -> float:
        """The distance travelled between clock times ``ta`` and ``tb``, every move's
        part counted (a move out and back between them is its whole length, not the
        net displacement); moves older than :data:`HISTORY_S` are forgotten."""
        with self._lock:
            total, t_next = 0.0, math.inf
            current = (self._t0, self._start, self._target, self._v, self._a)
            for t0, start, target, v, a in itertools.chain((current,), reversed(self._past)):
                if t_next <= ta:          # this move and those before it ended before ta
                    break
                lo, hi = max(ta, t0), min(tb, t_next)
                if hi > lo:
                    total += abs(_profile(start, target, v, a, hi - t0)
                                 - _profile(start, target, v, a, lo - t0))
                t_next = t0
            return total

    def end_time(self) -> float:
        """Clock time at which the move under way ends (or ended)."""
        with self._lock:
            return self._t0 + self._duration()

    def stop(self) -> None:
        """Stop where the axis is now (quick stop)."""
        with self._lock:
            now = self._clock()
            here = self._position_at(now)
            self._supersede(now)
            self._start = self._target = here
            self._t0 = now

    def _supersede(self, now: float) -> None:
        """Remember the move under way (a new one starts ``now``); forget those that
        ended more than :data:`HISTORY_S` ago."""
        self._past.append((self._t0, self._start, self._target, self._v, self._a))
        while len(self._past) > 1 and self._past[1][0] < now - HISTORY_S:
            self._past.pop(0)

    def _duration(self) -> float:
        d = abs(self._target - self._start)
        v, a = self._v, self._a
        if d == 0:
            return 0.0
        if d < v * v / a:  # triangular profile
            return 2 * math.sqrt(d / a)
        return d / v + v / a

    def _position_at(self, now: float) -> float:
        if now < self._t0:    # before this move was commanded: on the moves before it
            for t0, start, target, v, a in reversed(self._past):
                if now >= t0:
                    return _profile(start, target, v, a, now - t0)
            return self._past[0][1] if self._past else self._start
        return _profile(self._start, self._target, self._v, self._a, now - self._t0)

    def position(self) -> float:
        """The motor's position now (what its encoder reads)."""
        with self._lock:
            return self._position_at(self._clock())

    def link_position(self, t: float | None = None) -> float:
        """The link's position now (or at clock time ``t``): the motor's plus the play of
        the move under way (module docstring)."""
        with self._lock:
            return self._position_at(self._clock() if t is None else t) + self.play

    @property
    def target(self) -> float:
        return self._target

    def profile_ratio(self) -> tuple[float, float]:
        """The move under way's (or the last one's) velocity and acceleration as
        fractions of the axis's defaults: ``(1, 1)`` for a move at the configured profile."""
        with self._lock:
            return self._v / self.velocity, self._a / self.acceleration

    def target_reached(self) -> bool:
        with self._lock:
            return self._clock() - self._t0 >= self._duration()


def _profile(start: float, target: float, v: float, a: float, t: float) -> float:
    """Position ``t`` s into a trapezoidal move from ``start`` to ``target`` (velocity
    ``v``, acceleration ``a``): ``start`` before it, ``target`` after it."""
    d = target - start
    dist = abs(d)
    if dist == 0:
        return target
    if t <= 0.0:
        return start
    if dist < v * v / a:
        t_acc = math.sqrt(dist / a)
        v_peak = a * t_acc
        t_flat = 0.0
    else:
        t_acc = v / a
        v_peak = v
        t_flat = (dist - v * t_acc) / v
    total = 2 * t_acc + t_flat
    if t >= total:
        s = dist
    elif t < t_acc:
        s = 0.5 * a * t * t
    elif t < t_acc + t_flat:
        s = 0.5 * a * t_acc * t_acc + v_peak * (t - t_acc)
    else:
        td = total - t
        s = dist - 0.5 * a * td * td
    return start + math.copysign(s, d)
