"""The safety envelope of a session: what the station may command, and what it
watches while the robot moves.

Generic over the robot (the arm's session uses it; the wrist's can):

* **Actuator limits** from the station config (``[envelope] qm_min, qm_max``,
  actuator units): :func:`limit_violation` names the axis and the limit a target
  would cross. A planner draws again rather than plan such a pose, and the
  session checks every pose again before it moves.
* **Live watch** (:func:`watched_move`): the move is started, and while it runs
  every channel is read and compared with what the current model predicts
  (``predict(qm) -> {channel: value}``, ``qm`` one pose or a stack of them) *where the
  actuators were when the reading was sampled*. Each reading comes with the interval
  it was sampled in (:meth:`drivers.rig.Rig.read_timed`: the draw-wire between its
  request and its answer, the actuators at their SYNC, an inclinometer frame up to
  ``[envelope] latency`` s before it arrived); the actuators are read before and after
  the sensors, and since each axis moves one way during a move, its position over
  that interval lies between the actuator readings that bracket it. The reading
  departs where it is farther than its tolerance (``[envelope.tolerance]``, channel
  units: m, rad) from every prediction over that box of positions.
  A departure stops the robot where it is; the reading is then taken again at rest
  (no timing left to doubt) and compared with the prediction there. Where it still
  departs, :class:`EnvelopeStop` says which channel, by how much, and where, and the
  session does not record the pose and re-plans from what it has learnt; where it
  agrees, the sensor was only late (a frame older than the latency, a starved
  process) and the move goes on, at most :data:`MAX_CONFIRM` times a move.

Pure helpers plus one loop over :class:`drivers.rig.Rig`; no session state here.
"""
from __future__ import annotations

import logging
import math
import time
from typing import Callable, Mapping

import numpy as np

from calibration import simulate
from calibration.errors import StationError

log = logging.getLogger("station.planning.envelope")

ANGLE_CHANNELS = ("tilt", "roll", "pitch", "yaw")
#: actuator values closer than this (actuator units) to the target: the move is ending
NEAR_TARGET = 1e-3

Predict = Callable[[np.ndarray], Mapping[str, float]]


class EnvelopeStop(StationError):
    """The live readings left the model's prediction by more than the tolerance; the
    robot was stopped at ``qm``. ``departed``: channel -> (reading, predicted)."""

    def __init__(self, message: str, departed: dict, qm, readings: dict | None = None):
        super().__init__(message)
        self.departed = departed
        self.qm = np.asarray(qm, dtype=float)
        #: the sensors' readings at rest where it stopped (a departure confirmed at
        #: rest: what the robot really does there, which the next plan learns from)
        self.readings = dict(readings or {})


def limit_violation(qm, env) -> str | None:
    """What ``qm`` would cross of the config's actuator limits (``env``:
    :class:`drivers.config.EnvelopeConfig`), in words; None inside them."""
    qm = np.asarray(qm, dtype=float)
    for i, v in enumerate(qm):
        if env.qm_min is not None and v < env.qm_min[i]:
            return f"actuator {i + 1} target {v:.4g} is below its limit qm_min {env.qm_min[i]:.4g}"
        if env.qm_max is not None and v > env.qm_max[i]:
            return f"actuator {i + 1} target {v:.4g} is above its limit qm_max {env.qm_max[i]:.4g}"
    return None


def within_limits(env) -> Callable[[np.ndarray | None, np.ndarray], bool]:
    """A planner's ``accept(X, qm)``: True where ``qm`` is inside the config's actuator
    limits (``X``, the planned pose, is not needed)."""
    return lambda X, qm: limit_violation(qm, env) is None


def departures(readings: Mapping[str, float], predicted, tolerance: Mapping[str, float]
               ) -> dict[str, tuple[float, float]]:
    """Channels whose reading departs from the predictions by more than their tolerance:
    channel -> (reading, nearest prediction).

    predicted: ``{channel: value or values}`` or a list of ``{channel: value}`` (the
    predictions over the positions the robot went through while the reading was
    sampled). The robot moved continuously, so a reading is explained by any value
    between the least and the largest prediction; angles are compared modulo 2 pi
    (the predictions' span taken the short way round)."""
    if isinstance(predicted, Mapping):
        preds = {ch: np.atleast_1d(np.asarray(v, dtype=float)) for ch, v in predicted.items()}
    else:
        preds = {ch: np.array([float(p[ch]) for p in predicted]) for ch in predicted[0]}
    out = {}
    for ch, p in preds.items():
        if ch not in tolerance or ch not in readings or not np.all(np.isfinite(p)):
            continue      # not predicted here (NaN: beyond the sensor's range, unreadable)
        v = float(readings[ch])
        if ch in ANGLE_CHANNELS:          # relative to the first prediction, the short way
            rel = _wrap(p - p[0])
            lo, hi, x = float(rel.min()), float(rel.max()), float(_wrap(v - p[0]))
            nearest = float(p[0] + min(max(x, lo), hi))
        else:
            lo, hi, x = float(p.min()), float(p.max()), v
            nearest = min(max(x, lo), hi)
        if max(lo - x, x - hi) > tolerance[ch]:
            out[ch] = (v, nearest)
    return out


def _wrap(a):
    return (np.asarray(a) + math.pi) % (2 * math.pi) - math.pi


def describe(departed: dict, tolerance: Mapping[str, float]) -> str:
    unit = lambda ch: "rad" if ch in ANGLE_CHANNELS else "m"  # noqa: E731
    return "; ".join(f"{ch} read {r:.4g} {unit(ch)}, the model predicts {p:.4g} {unit(ch)} "
                     f"(tolerance {tolerance[ch]:.3g} {unit(ch)})"
                     for ch, (r, p) in departed.items())


#: how often a move may go on after a departure that the reading at rest did not confirm
MAX_CONFIRM = 5


class Track:
    """The actuator readings of one move: ``(since, until, qm)``, in the order read."""

    def __init__(self, n: int):
        self.n = n
        self.rows: list[tuple[float, float, np.ndarray]] = []

    def add(self, timed: Mapping[str, tuple]) -> np.ndarray:
        """Add the actuator channels of one :meth:`~drivers.rig.Rig.read_timed`; their qm."""
        qm = np.array([timed[f"qm{i + 1}"][0] for i in range(self.n)])
        since, until = timed["qm1"][1], timed["qm1"][2]
        self.rows.append((since, until, qm))
        return qm

    def box(self, since: float, until: float) -> np.ndarray:
        """``(n, 2)`` bounds of every axis over ``[since, until]``: between the last reading
        sampled before ``since`` and the first sampled after ``until`` (an axis moves one
        way during a move), every reading in between included."""
        before = [k for k, r in enumerate(self.rows) if r[1] <= since]
        after = [k for k, r in enumerate(self.rows) if r[0] >= until]
        a = before[-1] if before else 0
        b = after[0] if after else len(self.rows) - 1
        q = np.array([r[2] for r in self.rows[a:b + 1]])
        return np.column_stack([q.min(axis=0), q.max(axis=0)])


def box_points(box: np.ndarray) -> np.ndarray:
    """The corners and the centre of a box ``(n, 2)`` (corners once per moving axis)."""
    moving = [i for i in range(len(box)) if box[i, 1] > box[i, 0]]
    pts = np.tile(box[:, 0], (2 ** len(moving), 1))
    for bit, i in enumerate(moving):
        pts[:, i] = np.where((np.arange(len(pts)) >> bit) & 1, box[i, 1], box[i, 0])
    return np.vstack([pts, box.mean(axis=1)])


def live_departures(timed: Mapping[str, tuple], track: Track, predict: Predict,
                    tolerance: Mapping[str, float]) -> dict[str, tuple[float, float]]:
    """:func:`departures` of each watched sensor reading of ``timed`` against the
    predictions over the positions the actuators went through while it was sampled. A
    channel the method does not predict (the tilt of an sm-distance session at a
    station with an inclinometer) is not watched."""
    out = {}
    for ch, (v, since, until) in timed.items():
        if ch in tolerance:
            pred = predict(box_points(track.box(since, until)))
            if ch in pred:
                out.update(departures({ch: v}, {ch: pred[ch]}, tolerance))
    return out


def at_rest(rig, predict: Predict, env, settle: int = 10) -> tuple[dict, np.ndarray, dict]:
    """Departures of a reading taken with the robot at rest from the prediction there,
    the qm, and the sensors' readings. A late sensor shows the rest only after its lag: the reading is taken
    again (frames older than the last discarded) until each watched channel stays
    within a twentieth of its tolerance from one reading to the next (at most
    ``settle`` readings, ``[envelope] latency`` apart)."""
    last = None
    for _ in range(settle):
        time.sleep(env.latency)
        rig.discard_pending()
        r = {ch: v for ch, (v, _, _) in rig.read_timed().items()}
        if last is not None and all(abs(float(_wrap(r[ch] - last[ch])) if ch in ANGLE_CHANNELS
                                        else r[ch] - last[ch]) <= tol / 20
                                    for ch, tol in env.tolerance.items() if ch in r):
            break
        last = r
    n = sum(1 for ch in r if ch.startswith("qm"))
    qm = np.array([r[f"qm{i + 1}"] for i in range(n)])
    sensors = {ch: float(v) for ch, v in r.items() if not ch.startswith("qm")}
    return departures(r, predict(qm[None, :]), env.tolerance), qm, sensors


def watched_move(rig, target, predict: Predict, env, timeout: float) -> int:
    """Move to ``target`` (actuator values) while watching the live readings against
    ``predict``; stop there and raise :class:`EnvelopeStop` where they depart (the
    departure confirmed at rest). Without a prediction (``predict`` None) this is a
    plain move. Returns how often the move was halted for a departure that the
    reading at rest did not confirm."""
    if predict is None:
        rig.move_to(target, timeout)
        return 0
    target = np.asarray(target, dtype=float)
    n = len(target)
    end = time.monotonic() + timeout
    unconfirmed = 0
    track = Track(n)
    start = track.add(rig.read_timed(actuators_only=True))       # where the move starts
    rig.start_move(target)
    arrival = predicted_arrival(rig, start, target)
    while True:
        timed = rig.read_timed()                # actuators first, then the sensors,
        track.add(timed)
        qm = track.add(rig.read_timed(actuators_only=True))   # and the actuators again
        bad = live_departures(timed, track, predict, env.tolerance)
        if bad:
            rig.stop()
            rest, qm, sensors = at_rest(rig, predict, env)
            if rest:
                raise EnvelopeStop(f"stopped at qm {np.round(qm, 4).tolist()}: "
                                   + describe(rest, env.tolerance), rest, qm, sensors)
            unconfirmed += 1
            if unconfirmed > MAX_CONFIRM:
                raise EnvelopeStop(
                    f"stopped at qm {np.round(qm, 4).tolist()}: while moving, "
                    + describe(bad, env.tolerance) + f"; at rest the readings agree, {unconfirmed} "
                    "times this move: the sensors lag the actuators by more than [envelope] "
                    f"latency ({env.latency:g} s) of the station config", bad, qm)
            log.info("envelope: %s while moving, not at rest: the move goes on",
                     describe(bad, env.tolerance))
            track = Track(n)
            start = track.add(rig.read_timed(actuators_only=True))
            rig.start_move(target)
            arrival = predicted_arrival(rig, start, target)
            continue
        if np.max(np.abs(qm - target)) <= NEAR_TARGET or time.monotonic() > end:
            rig.wait_moved(max(0.1, end - time.monotonic()))
            return unconfirmed
        time.sleep(nap(env.poll, arrival))


#: s between readings once the predicted arrival has passed (the drive's own profile
#: may end a little later than its profile velocity and acceleration say)
ARRIVAL_POLL = 0.005


def move_duration(start, target, velocity, acceleration) -> float:
    """Seconds a move from ``start`` to ``target`` (actuator units, per axis) takes on
    trapezoidal profiles of ``velocity`` (units/s) and ``acceleration`` (units/s^2) per
    axis, each axis on its own (the slowest axis ends the move)."""
    d = np.abs(np.asarray(target, dtype=float) - np.asarray(start, dtype=float))
    v = np.broadcast_to(np.asarray(velocity, dtype=float), d.shape)
    a = np.broadcast_to(np.asarray(acceleration, dtype=float), d.shape)
    t = np.where(d < v * v / a, 2 * np.sqrt(d / a), d / v + v / a)
    return float(t.max()) if t.size else 0.0


def predicted_arrival(rig, start, target) -> float | None:
    """``time.monotonic()`` at which a move started now from ``start`` to ``target``
    ends by the drives' profile velocity and acceleration (None where the station
    config does not set them: the drives' own profile is not known)."""
    act = getattr(rig, "actuators", None)
    v, a = getattr(act, "velocity", None), getattr(act, "acceleration", None)
    if v is None or a is None:
        return None
    return time.monotonic() + move_duration(start, target, v, a)


def nap(poll: float, arrival: float | None) -> float:
    """How long the watch sleeps before its next reading: ``poll``, but no later than
    the predicted ``arrival`` (then :data:`ARRIVAL_POLL` until the move ends), so that
    a move is not watched for up to ``poll`` after it ended."""
    if arrival is None:
        return poll
    left = arrival - time.monotonic()
    return min(poll, left) if left > 0 else min(poll, ARRIVAL_POLL)


def sm_predictor(method: str, robot, xi, reference_qm, distance_off: float = 0.0,
                 tilt_ref: float | None = None) -> Predict:
    """What the arm's sensors should read at ``qm`` (one pose ``(n,)``: floats; a stack
    ``(m, n)``: arrays) under the model ``xi``: the draw-wire's distance from the
    reference (plus ``distance_off``) and, for sm-distance-tilt, the tilt of the last
    link. sm-distance at a station with an inclinometer (``tilt_ref``: its reading at
    the reference): the tilt too, as the reference's reading turned by the model's
    change of the last link's angle from the reference (the inclinometer's own zero and
    the unidentified offsets cancel)."""
    xi = np.array(xi, dtype=float)
    ref = np.asarray(reference_qm, dtype=float)
    phi_ref = (float(robot.fk(ref[None, :], xi)[0, 3])
               if method == "sm-distance" and tilt_ref is not None else None)

    def predict(qm):
        qm = np.asarray(qm, dtype=float)
        m = simulate.measure(method, robot, xi, np.atleast_2d(qm), reference_qm=ref)
        out = {ch: np.asarray(v, dtype=float).reshape(-1) + (distance_off if ch == "distance"
                                                              else 0.0)
               for ch, v in m.items()}
        if phi_ref is not None:
            phi = robot.fk(np.atleast_2d(qm), xi)[:, 3]
            out["tilt"] = tilt_ref + _wrap(phi - phi_ref)
        return out if qm.ndim == 2 else {ch: float(v[0]) for ch, v in out.items()}
    return predict
