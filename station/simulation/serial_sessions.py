"""Whole simulated sessions on a robot file's arm (:mod:`station.simulation.sessions`).

A robot file's arm is drawn around the file's nominal
(:func:`drivers.sim.truth.draw_truth` on its ``SerialSpec``) and scored against
:func:`equivalent_truth`: what the session's own model reaches on noise-free
readings of that truth, its uncalibrated parameters left where the session left
them. A wrong start value of an uncalibrated parameter that influences the model
(the tool's offset, the base's tilt about its vertical...) moves the calibrated
ones alike in every session; that is not an error of the calibration.

Nothing here is used by a real station; it needs the simulator.
"""
from __future__ import annotations

import copy
import dataclasses
import json
from pathlib import Path

import numpy as np

from calibration.solver import SolverOptions, solve
from drivers.robot_file import load_robot_file
from drivers.sim.serial_robot import sim_config_data
from drivers.sim.truth import SimTruth, draw_truth

#: The station's devices on a robot file's arm (a dual-axis tool inclinometer).
SERIAL_NOISE = {"distance": 1e-5, "roll": 1.7e-4, "pitch": 1.7e-4, "qm": 0.0}
MOUNT_SPREAD = 0.01   # rad, the tool inclinometer mounted up to this much off square


def serial_truth(robot_file, seed: int, comment: str, **draw) -> SimTruth:
    """An arm of ``robot_file`` drawn with ``default_rng(seed)`` around its nominal, the
    devices' noise (:data:`SERIAL_NOISE`), its inclinometer's mount drawn within
    +-:data:`MOUNT_SPREAD`; the simulator's noise seeded by ``seed`` too."""
    rng = np.random.default_rng(seed)
    path = Path(robot_file).resolve()
    truth = draw_truth(load_robot_file(path), rng, noise=SERIAL_NOISE, seed=seed,
                       comment=comment, **draw)
    mount = tuple(float(v) for v in rng.uniform(-MOUNT_SPREAD, MOUNT_SPREAD, 2))
    return dataclasses.replace(truth, robot_file=str(path), inclinometer_mount=mount)


def serial_config(robot_file, folder: Path, velocity: float = 6.0,
                  acceleration: float = 60.0) -> Path:
    """The simulated station of a robot file (:func:`drivers.sim.serial_robot.sim_config_data`)
    naming it (``robot_file``), with the axes' ``velocity`` and ``acceleration``, as
    ``folder/station.toml``."""
    data = sim_config_data(load_robot_file(robot_file), velocity=velocity,
                           acceleration=acceleration)
    lines = [f'robot_file = "{robot_file}"']

    def emit(prefix, table):
        lines.append(f"[{prefix}]")
        lines.extend(f"{k} = {json.dumps(v)}" for k, v in table.items() if not isinstance(v, dict))
        for k, v in table.items():
            if isinstance(v, dict):
                emit(f"{prefix}.{k}", v)

    for key in ("canopen", "inclinometer", "drawwire", "snapshot"):
        emit(key, data[key])
    path = Path(folder) / "station.toml"
    path.write_text("\n".join(lines) + "\n")
    return path


def serial_truth_vector(model, truth: SimTruth, state: dict) -> np.ndarray:
    """A robot file's truth in the order of ``model.names``: the robot's parameters,
    ``distance_off`` from the simulator's state, the tool inclinometer's mount."""
    known = dict(truth.parameters)
    known["mount_x"], known["mount_y"] = truth.inclinometer_mount
    if state.get("drawwire_offset") is not None:
        known["distance_off"] = -float(state["drawwire_offset"])
    missing = [n for n in model.names if n not in known]
    if missing:
        raise ValueError(f"the truth has no value for {missing}")
    return np.array([known[n] for n in model.names], dtype=float)


def equivalent_truth(model, result, x_truth) -> tuple[np.ndarray, float]:
    """What ``model`` calibrates from noise-free readings of the truth ``x_truth``, its
    uncalibrated parameters (``result``'s not identifiable) held where ``result`` left
    them (module doc); and the RMS of the residual left there in units of
    ``result.sigma``: 0 where the model's form can express the truth."""
    r_truth = model.evaluate(x_truth)[0]
    evaluate = model.evaluate

    def noise_free(x):
        r, W = evaluate(x)
        return r - r_truth, W

    twin = copy.copy(model)
    twin.evaluate = noise_free
    twin.x0 = np.array(result.x, dtype=float)
    fixed = tuple(n for n, st in zip(result.names, result.status) if not st.identifiable)
    eq = solve(twin, SolverOptions(sigma=dict(result.sigma), fixed=fixed, recheck=False))
    sig = np.array([result.sigma[ch] for ch in model.channels])[np.asarray(model.row_channel)]
    left = float(np.sqrt(np.mean((eq.residual / sig) ** 2)))
    return eq.x, left


def serial_errors(session, truth: SimTruth, state: dict) -> tuple[list[str], np.ndarray]:
    """Names and ``(calibrated - equivalent truth) / std`` of the identifiable
    parameters (every difference taken modulo 2 pi: the angles'; the lengths' are far
    below)."""
    res, model = session.outcome.result, session.outcome.model
    x_eq, left = equivalent_truth(model, res, serial_truth_vector(model, truth, state))
    if left > 1e-3:
        raise ValueError(f"the session's model cannot express the truth: residual "
                         f"{left:.3g} sigma left on noise-free readings")
    ok = np.array([st.identifiable for st in res.status])
    d = (res.x - x_eq + np.pi) % (2 * np.pi) - np.pi
    return [n for n, o in zip(res.names, ok) if o], d[ok] / res.std[ok]
