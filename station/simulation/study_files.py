"""Studies of a robot file's or URDF robot's arm (``app.py study --robot FILE``).

One calibration of the study (:func:`run_one`, what :func:`station.simulation.study.run_one`
hands a robot that is not a built-in): a robot drawn around the file's nominal (a robot
file's: :func:`station.simulation.serial_sessions.serial_truth`; a URDF robot's, with an
instrument and points on its tool: :func:`station.simulation.urdf_sessions.urdf_truth`),
a trace simulated of it (:func:`station.simulation.tracegen_serial.generate`; sm-markers:
poses inside the joint limits, random or the D-optimal choice of a pool,
:func:`station.planning.marker_plan.plan`), calibrated by the one path every caller takes
(:func:`station.fitting.batch.calibrate`) and compared with the truth *in the fit's own
terms*: the same poses' noise-free readings calibrated the same way (parameters that are
held, or not identifiable, take the same values in both), so that ``(estimate - truth) /
std`` over the identifiable parameters is the honesty of the reported std. The held-out
error is the calibrated model's on fresh poses the plan never saw.
"""
from __future__ import annotations

import math
import time

import numpy as np

from calibration.errors import CalibrationError, StationError

#: the instrument's noise of a study of sm-markers (m, each coordinate): a motion capture
MARKER_NOISE = 1e-4


def _seed(spec, index: int) -> int:
    return int(np.random.default_rng([spec.seed, index]).integers(2 ** 31))


def _markers_trace(spec, robot, index: int, design: str, *, noise: bool, count=None):
    """``(trace, x_true, u)`` of sm-markers on the URDF robot ``spec.robot``."""
    from station.planning import marker_plan
    from station.planning.request import PlanRequest
    from station.recording.trace import Trace
    from station.simulation import tracegen_urdf
    from station.simulation.urdf_sessions import urdf_truth

    truth, x = urdf_truth(spec.robot, _seed(spec, index), "study")
    u = np.asarray(truth.points, dtype=float)
    n = count or spec.count or 6 * robot.n_actuators + 10
    rng = np.random.default_rng([spec.seed, index, 1])
    if design == "optimal":
        sight = marker_plan.Sight(volume_min=(-1e3,) * 3, volume_max=(1e3,) * 3,
                                  viewpoint=(0.0, 0.0, 0.0), max_angle=math.pi)
        qm, use, _ = marker_plan.plan(robot, x, u, sight,
                                      PlanRequest(count=n, validation=0, seed=index))
    else:
        qm = tracegen_urdf.draw_poses(robot, n, rng, margin=marker_plan.MARGIN)
    sigma = float(spec.noise.get("marker", MARKER_NOISE))
    P = tracegen_urdf.readings(robot, x, u, qm, np.random.default_rng([spec.seed, index, 2]),
                               sigma if noise else 0.0)
    header = {"robot": robot.name, "robot_file": dict(robot.spec.source), "method": "sm-markers",
              "markers": int(len(u)), "nominal": {},
              "sigma": {"marker": sigma}}
    poses = [{"index": i, "qm": [float(v) for v in q],
              "markers": [[float(c) for c in p] for p in P[i]]} for i, q in enumerate(qm)]
    return Trace(f"<study robot {index}>", header, None, poses), np.r_[x, u.reshape(-1)]


def _file_trace(spec, robot, index: int, station_noise: dict, *, noise: bool, count=None,
                poses: int = 1):
    """``(trace, x_true)`` of a distance method on the robot file's arm (``poses``: which
    draw of poses; 2: the held-out ones)."""
    from drivers.sim.truth import draw_truth
    from station.recording.trace import Trace
    from station.simulation import tracegen_serial
    truth = draw_truth(robot.spec, np.random.default_rng([spec.seed, index]), gear=spec.gear,
                       length=spec.length, offset=spec.offset)
    xi = truth.xi()
    sig = {**station_noise, **spec.noise} if noise else {}
    header, reference, poses = tracegen_serial.generate(
        robot, spec.method, xi, noise=sig, seed=[spec.seed, index, poses],
        count=count or spec.count)
    if not noise:
        header["sigma"] = {k: v for k, v in station_noise.items()
                           if k in ("distance", "tilt")}
    return Trace(f"<study robot {index}>", header, reference, poses), xi


def run_one(spec, index: int, design: str, station_noise: dict, held_out: int) -> dict:
    """One calibration of the study (module doc), the devices' ``station_noise`` and
    ``held_out`` fresh poses (the study's); never raises for a failed calibration."""
    from calibration.robots import get_robot
    from drivers.robot_file import load_robot_file
    from station.fitting.batch import calibrate

    robot = get_robot(load_robot_file(spec.robot))
    markers = spec.method == "sm-markers"
    out = {"index": index, "design": design, "ok": False}
    t0 = time.perf_counter()
    try:
        if markers:
            trace, x_true = _markers_trace(spec, robot, index, design, noise=True)
            clean, _ = _markers_trace(spec, robot, index, design, noise=False)
        else:
            trace, x_true = _file_trace(spec, robot, index, station_noise, noise=True)
            clean, _ = _file_trace(spec, robot, index, station_noise, noise=False)
        outcome = calibrate(trace, accept_poor_fit=True)
        eq = calibrate(clean, accept_poor_fit=True).result
    except (CalibrationError, StationError) as e:
        out.update(error=str(e), seconds=time.perf_counter() - t0)
        return out
    res = outcome.result
    ident = [j for j, st in enumerate(res.status) if st.identifiable]
    diff = res.x - eq.x
    out["truth"] = {res.names[j]: float(eq.x[j]) for j in ident}
    z = {res.names[j]: float(diff[j] / res.std[j]) for j in ident}
    err = {res.names[j]: float(diff[j]) for j in ident}
    held = _held_out(spec, robot, index, res, x_true, markers, station_noise, held_out)
    out.update(ok=True, poses=int(outcome.model.n_poses), iterations=int(res.iterations),
               z=z, error=err, heldout_rms=held, seconds=time.perf_counter() - t0)
    return out


def _held_out(spec, robot, index: int, res, x_true, markers: bool, station_noise: dict,
              held_out: int) -> dict:
    """The calibrated model's error on ``held_out`` fresh poses of the true robot
    (noise-free)."""
    from calibration.methods import build

    try:
        if markers:
            from station.planning.marker_plan import MARGIN
            from station.simulation.tracegen_urdf import draw_poses

            n = robot.n_params
            qm = draw_poses(robot, held_out, np.random.default_rng([spec.seed, index, 3]),
                            margin=MARGIN)
            T = robot.frames(qm, x_true[:n])
            P = T[:, None, :3, 3] + np.einsum("mij,kj->mki", T[:, :3, :3],
                                              x_true[n:].reshape(-1, 3))
            Th = robot.frames(qm, res.x[:n])
            Q = Th[:, None, :3, 3] + np.einsum("mij,kj->mki", Th[:, :3, :3],
                                               res.x[n:].reshape(-1, 3))
            return {"marker": float(np.sqrt(np.mean(np.sum((P - Q) ** 2, axis=2))))}
        trace, _ = _file_trace(spec, robot, index, station_noise, noise=False, count=held_out,
                               poses=3)
        hm = build(spec.method, robot, trace.method_data(), res.x)
        r = hm.residuals(res.x)
        return {ch: float(np.sqrt(np.mean(r[hm.row_channel == k] ** 2)))
                for k, ch in enumerate(hm.channels)}
    except CalibrationError as e:
        return {"error": str(e)}
