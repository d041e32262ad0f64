"""Whole simulated sessions over drawn robots, scored against their truth.

The Monte Carlo of issue 10 (``bench/bench_sessions.py``, the slow session
tests): a robot drawn around the nominal (:func:`drivers.sim.truth.draw_truth`)
with the noise real devices have, the simulator in its own process
(:class:`drivers.sim.simulator_process.SimulatorProcess`), one unattended
:meth:`station.session.session.Session.run`, and the result compared with the truth
*in the frame the session captured*: for sm-distance-tilt the base origin is
where the true end effector was at the reference (the draw-wire anchor), and
``distance_off`` is the reading the simulated draw-wire gives where the true
distance is 0 (minus the length it read when zeroed).

``robot`` may also be a robot file's path (:mod:`station.simulation.serial_sessions`: the truth
in the session's own terms is :func:`~station.simulation.serial_sessions.equivalent_truth`).

Nothing here is used by a real station; it needs the simulator.
"""
from __future__ import annotations

import dataclasses
import math
import time
import tomllib
import traceback
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from calibration.errors import StationError
from drivers.config import load_station_config
from drivers.endpoints import with_endpoints
from drivers.robot_file import is_robot_file
from drivers.sim.serial_robot import ACCELERATION, VELOCITY
from drivers.sim.truth import SimTruth, draw_truth, save_truth
from station.simulation.serial_sessions import serial_config, serial_truth
from station.simulation.session_scores import (SessionScore, correlation, excursion,
                                               normalized_errors, residual_offset, tool_error)

ROOT = Path(__file__).resolve().parents[2]

#: Std of one reading as the station's devices have them: a draw-wire of 1 um
#: resolution and 10 um repeatability, an inclinometer of 0.01 deg, encoders whose
#: noise is below their resolution.
DEVICE_NOISE = {"agebot-sm": {"distance": 1e-5, "tilt": 1.7e-4, "roll": 1.7e-4,
                              "pitch": 1.7e-4, "qm": 0.0},
                "agebot-pm": {"roll": 1.7e-4, "pitch": 1.7e-4, "yaw": 1.7e-3, "qm": 0.0}}
DEFAULT_METHOD = {"agebot-sm": "sm-distance-tilt", "agebot-pm": "pm-fk"}


def station_truth(robot: str, seed: int, **draw) -> SimTruth:
    """A robot drawn with ``default_rng(seed)`` around the nominal, with the devices'
    noise (:data:`DEVICE_NOISE`) and the simulator's noise seeded by ``seed`` too; a
    robot file's arm where ``robot`` is its path (:func:`station.simulation.serial_sessions.serial_truth`)."""
    comment = f"drawn by station.simulation.sessions, seed {seed}"
    if is_robot_file(str(robot)):
        return serial_truth(robot, seed, comment, **draw)
    rng = np.random.default_rng(seed)
    return draw_truth(robot, rng, noise=DEVICE_NOISE[robot], seed=seed, comment=comment,
                      **draw)


def fast_config(robot: str, folder: Path, speed: float = 4.0, truth: SimTruth | None = None,
                margin: float = 0.95) -> Path:
    """The simulated station's config with moves ``speed`` times faster (velocity
    ``speed``, acceleration ``speed**2``): the same devices, shorter sessions. With
    ``truth``, the envelope's actuator limits are that robot's travel times ``margin``
    (what a station's config takes from the robot's data sheets)."""
    name = "sim-sm.toml" if robot == "agebot-sm" else "sim-pm.toml"
    text = (ROOT / "fixtures" / "stations" / name).read_text()
    data = tomllib.loads(text)
    out = text
    for key, f in (("profile_velocity", speed), ("profile_acceleration", speed * speed)):
        v = data["canopen"][key]
        out = out.replace(f"{key} = {_toml(v)}", f"{key} = {_toml(_scale(v, f))}")
    if out == text and speed != 1.0:
        raise ValueError(f"{name}: profile_velocity/profile_acceleration not found to scale")
    env = data.get("envelope", {})
    if truth is not None and "qm_min" in env:
        from drivers.sim.robot import SimulatedAgebot

        lim = SimulatedAgebot(truth).physical_limits()
        if all(v is not None for v in lim):
            mid = np.array([(a + b) / 2 for a, b in lim])
            half = np.array([(b - a) / 2 for a, b in lim]) * margin
            for key, v in (("qm_min", mid - half), ("qm_max", mid + half)):
                out = out.replace(f"{key} = {_toml(env[key])}", f"{key} = {_toml(list(v))}")
    path = Path(folder) / name
    path.write_text(out)
    return path


def _scale(v, f):
    return [x * f for x in v] if isinstance(v, list) else v * f


def _toml(v) -> str:
    return "[" + ", ".join(repr(float(x)) for x in v) + "]" if isinstance(v, list) else repr(float(v))


@dataclass
class SimRun:
    """One unattended session against the simulator: the :class:`Session` (closed),
    whether it ran to its parameter file, what stopped it (and whether that was the
    station's named refusal), the simulator's state at the end and the seconds it took."""

    session: object
    completed: bool
    error: str
    state: dict
    seconds: float
    refused: bool = False


def simulated_session(truth: SimTruth, folder: Path, method: str, request, config: Path,
                      seed: int, robot: str | None = None) -> SimRun:
    """Run one unattended session on the simulated ``truth`` (its own process, the
    station ``config``) in ``folder / "run"``; the traceback of a failure is kept in
    ``folder / "error.txt"``. Shared by the arm's, the wrist's and the URDF robot's
    Monte Carlo (``robot``: the simulator's ``--robot``, a URDF robot's
    :func:`~drivers.robot_file.urdf_ref`; default the truth's robot file or robot)."""
    from drivers.sim.server import SimulatorProcess
    from station.session.session import Session

    folder = Path(folder)
    truth_file = folder / "truth.json"
    t0 = time.monotonic()
    completed, error, refused = False, "", False
    with SimulatorProcess(robot or truth.robot_file or truth.robot, truth=str(truth_file),
                          config=str(config), seed=seed) as sim:
        cfg = with_endpoints(load_station_config(config), sim.endpoints, source="simulator")
        s = Session(cfg, method, folder / "run", request=request)
        try:
            s.run()
            completed = True
        except Exception as e:   # the score says what went wrong; the bench goes on
            error = f"{type(e).__name__}: {e}"
            refused = isinstance(e, StationError)
            (folder / "error.txt").write_text(traceback.format_exc())
        finally:
            with sim.control() as ctl:
                state = ctl.call(state=True)
            s.close()
    return SimRun(s, completed, error, state, time.monotonic() - t0, refused)


def event_counts(session) -> dict[str, int]:
    """How many events of each kind the session recorded."""
    out: dict[str, int] = {}
    for ev in session.events:
        out[ev["kind"]] = out.get(ev["kind"], 0) + 1
    return out


def run_session(truth: SimTruth, folder: Path, *, method: str | None = None, seed: int = 0,
                request=None, speed: float = 4.0, grow: bool = True) -> SessionScore:
    """Run one unattended session on the simulated ``truth`` in ``folder`` and score it
    (``grow``: the arm in rounds, live-watched, as ``app.py run`` by default; False:
    ``--one-shot``)."""
    from station.planning.request import PlanRequest

    robot = truth.robot
    method = method or DEFAULT_METHOD.get(robot, "sm-distance-tilt")
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    save_truth(truth, folder / "truth.json")
    if truth.robot_file is not None:      # a robot file's arm: ``speed`` times the default
        cfg = serial_config(truth.robot_file, folder, velocity=VELOCITY * speed,
                            acceleration=ACCELERATION * speed * speed)
    else:
        cfg = fast_config(robot, folder, speed, truth)
    req = dataclasses.replace(request or PlanRequest(seed=seed), grow=grow)
    run = simulated_session(truth, folder, method, req, cfg, seed)
    s, state = run.session, run.state
    score = SessionScore(seed=seed, robot=robot, method=method, completed=run.completed,
                         error=run.error, refused=run.refused)
    score.poses, score.skipped = len(s.measured), len(s.skipped)
    score.events = event_counts(s)
    score.excursion = excursion(s, truth)
    if score.completed:
        score.names, score.z = normalized_errors(s, truth, state)
        score.corr = correlation(s.outcome.result, score.names)
        dof = s.outcome.result.sigma_dof
        score.dof = float(min(dof.values())) if dof else math.inf
        score.offset = residual_offset(s, truth, state)
        score.heldout = {v["channel"]: v["rms_after"] for v in s.outcome.validation or ()}
        if truth.spec is None:
            score.tool_error = tool_error(s, truth, state)
    return score
