"""The safety envelope of a session: what the station may command, and what it
watches while the robot moves.

Generic over the robot (the arm's session uses it; the wrist's can):

* **Actuator limits** from the station config (``[envelope] qm_min, qm_max``,
  actuator units): :func:`limit_violation` names the axis and the limit a target
  would cross. A planner draws again rather than plan such a pose, and the
  session checks every pose again before it moves.
* **Live watch** (:func:`watched_move`): the move is started, and while it runs
  every channel is read and compared with what the current model predicts at the
  actuator values read while moving (``predict(qm) -> {channel: value}``). A
  sensor's value is up to ``[envelope] latency`` s old when it arrives (an
  inclinometer sending 20 frames a second, a bus, a filter), so a reading must
  match the prediction somewhere along the path the actuators travelled over that
  time, not at the one instant they were read.
  Where a channel departs by more than its tolerance (``[envelope.tolerance]``,
  channel units: m, rad) the robot is stopped where it is and
  :class:`EnvelopeStop` says which channel, by how much, and where. The session
  then does not record the pose and re-plans from what it has learnt.

Pure helpers plus one loop over :class:`drivers.rig.Rig`; no session state here.
"""
from __future__ import annotations

import math
import time
from typing import Callable, Mapping

import numpy as np

from calibration import simulate
from calibration.errors import StationError

ANGLE_CHANNELS = ("tilt", "roll", "pitch", "yaw")
#: actuator values closer than this (actuator units) to the target: the move is ending
NEAR_TARGET = 1e-3

Predict = Callable[[np.ndarray], Mapping[str, float]]


class EnvelopeStop(StationError):
    """The live readings left the model's prediction by more than the tolerance; the
    robot was stopped at ``qm``. ``departed``: channel -> (reading, predicted)."""

    def __init__(self, message: str, departed: dict, qm):
        super().__init__(message)
        self.departed = departed
        self.qm = np.asarray(qm, dtype=float)


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
    """Channels whose reading departs from the prediction by more than their
    tolerance (angles compared modulo 2 pi): channel -> (reading, nearest prediction).

    predicted: one ``{channel: value}`` or several (the predictions along the path the
    robot travelled while the sensors were read, which do not read at one instant):
    the reading departs where it is farther than the tolerance from all of them."""
    preds = [predicted] if isinstance(predicted, Mapping) else list(predicted)
    out = {}
    for ch in preds[0]:
        if ch not in tolerance or ch not in readings:
            continue
        best, nearest = math.inf, None
        for p in preds:
            d = readings[ch] - p[ch]
            if ch in ANGLE_CHANNELS:
                d = (d + math.pi) % (2 * math.pi) - math.pi
            if abs(d) < best:
                best, nearest = abs(d), p[ch]
        if best > tolerance[ch]:
            out[ch] = (float(readings[ch]), float(nearest))
    return out


def describe(departed: dict, tolerance: Mapping[str, float]) -> str:
    unit = lambda ch: "rad" if ch in ANGLE_CHANNELS else "m"  # noqa: E731
    return "; ".join(f"{ch} read {r:.4g} {unit(ch)}, the model predicts {p:.4g} {unit(ch)} "
                     f"(tolerance {tolerance[ch]:.3g} {unit(ch)})"
                     for ch, (r, p) in departed.items())


def watched_move(rig, target, predict: Predict, env, timeout: float) -> None:
    """Move to ``target`` (actuator values) while watching the live readings against
    ``predict``; stop there and raise :class:`EnvelopeStop` where they depart.
    Without a prediction (``predict`` None) this is a plain move."""
    if predict is None:
        rig.move_to(target, timeout)
        return
    target = np.asarray(target, dtype=float)
    n = len(target)
    end = time.monotonic() + timeout
    # (time, qm) read while moving, from where the move starts
    history = [(time.monotonic(), np.array(rig.qm(), dtype=float))]
    rig.start_move(target)
    while True:
        r = rig.read()                      # actuators first, then the sensors
        now = time.monotonic()
        qa = np.array([r[f"qm{i + 1}"] for i in range(n)])
        qm = np.array(rig.qm(), dtype=float)  # and the actuators again after them
        history.append((now, qa))
        # the window of the sensors' lag, and the reading just before it
        old = [k for k, (t, _) in enumerate(history) if t < now - env.latency]
        history = history[old[-1]:] if old else history
        path = [q for _, q in history] + [qm]
        preds = [predict(a + f * (b - a)) for a, b in zip(path, path[1:]) for f in (0.0, 0.25, 0.5, 0.75)]
        bad = departures(r, preds + [predict(qm)], env.tolerance)
        if bad:
            rig.stop()
            raise EnvelopeStop(f"stopped at qm {np.round(qm, 4).tolist()}: "
                               + describe(bad, env.tolerance), bad, qm)
        if np.max(np.abs(qm - target)) <= NEAR_TARGET or time.monotonic() > end:
            rig.wait_moved(max(0.1, end - time.monotonic()))
            return
        time.sleep(env.poll)


def sm_predictor(method: str, robot, xi, reference_qm, distance_off: float = 0.0) -> Predict:
    """What the arm's sensors should read at ``qm`` under the model ``xi``: the
    draw-wire's distance from the reference (plus ``distance_off``) and, for
    sm-distance-tilt, the tilt of the last link."""
    xi = np.array(xi, dtype=float)
    ref = np.asarray(reference_qm, dtype=float)

    def predict(qm):
        m = simulate.measure(method, robot, xi, np.atleast_2d(qm), reference_qm=ref)
        return {ch: float(np.asarray(v).reshape(-1)[0]) + (distance_off if ch == "distance" else 0)
                for ch, v in m.items()}
    return predict
