"""Simulated stations of a URDF robot (docs/urdf-robots.md, "At the station"): a robot
drawn around the URDF's nominal, an instrument placed in a room, points on its tool.

:func:`urdf_truth` draws one as ``app.py truth draw --robot FILE.urdf`` and the session
tests do: every joint origin off by millimetres and milliradians and every joint's zero
by milliradians (:func:`station.simulation.tracegen_urdf.draw_truth`), written as the
TRUE URDF (the nominal's text with those origins, :func:`station.outputs.export_urdf.
calibrated_urdf`); a motion-capture room with z up within a degree, its origin a few
metres from the robot's base (:func:`~station.simulation.tracegen_urdf.draw_frame`);
:data:`POINTS` markers on a plate in front of the tool's flange (:func:`marker_plate`),
facing along the tip link's z as a motion capture's marker tree does.

:func:`urdf_config` writes the simulated station of such a truth (the URDF named at top
level, its axes as fast as asked, the room's ``[mocap]``), and :func:`run_urdf_session`
runs one unattended session on it and scores it
(:mod:`station.simulation.urdf_scores`: the calibrated points' predictions against the
truth's).

Nothing here is used by a real station; it needs the simulator.
"""
from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np

from calibration.robots import get_robot
from calibration.robots.serial import rpy_of
from drivers.config_reader import frozen_map
from drivers.robot_file import load_robot_file
from drivers.sim.truth import SimTruth, save_truth
from drivers.urdf_file import parse_urdf
from station.outputs.export_urdf import calibrated_urdf
from station.simulation import tracegen_urdf

#: markers on the tool, and the devices' noise: a motion capture's 0.1 mm per
#: coordinate, the station's own sensors as on a robot file's arm
POINTS = 3
URDF_NOISE = {"marker": 1e-4, "distance": 1e-5, "roll": 1.7e-4, "pitch": 1.7e-4, "qm": 0.0}
ROOM_TILT_DEG = 1.0      # the room's z within this of the base link's
ROOM_DISTANCE = 2.5      # m: the room's origin from the robot's base


def urdf_truth(ref: str, seed: int, comment: str, *, true_name: str = "truth-true.urdf",
               shift: float = tracegen_urdf.ORIGIN_SHIFT, turn: float = tracegen_urdf.ORIGIN_TURN,
               zero: float = tracegen_urdf.ZERO) -> tuple[SimTruth, np.ndarray]:
    """``(truth, x)``: a robot of the URDF robot ``ref`` drawn with ``default_rng(seed)``
    (module doc), its true URDF named ``true_name`` (beside the truth file,
    :func:`drivers.sim.truth.save_truth` writes it), and ``x`` the truth in the nominal
    robot's own parameters (the instrument frame in ``base_*``)."""
    spec = load_robot_file(ref)
    robot = get_robot(spec)
    rng = np.random.default_rng(seed)
    x = tracegen_urdf.draw_truth(robot, rng, shift=shift, turn=turn, zero=zero)
    R, t = tracegen_urdf.draw_frame(rng, vertical_tilt_deg=ROOM_TILT_DEG, distance=ROOM_DISTANCE)
    points = marker_plate(rng, POINTS)
    text = calibrated_urdf(robot, x)
    true = parse_urdf(text, true_name, spec.base_link, spec.tip_link, name=true_name)
    frame = (tuple(map(float, t)), tuple(map(float, rpy_of(np.asarray(R)[None])[0])))
    model = get_robot(true)
    truth = SimTruth(robot="urdf", parameters=frozen_map(model.as_dict(model.nominal)),
                     noise=frozen_map(dict(URDF_NOISE)), seed=seed, comment=comment,
                     spec=true, robot_file=true_name, frame=frame,
                     points=tuple(tuple(map(float, p)) for p in points))
    return truth, tracegen_urdf.frame_parameters(robot, x, R, t)


def marker_plate(rng, count: int) -> np.ndarray:
    """``(count, 3)`` markers on a plate in front of the flange (tip link frame, m): 3 to
    8 cm along z, within 8 cm of the axis and at least 3 cm from it and 4 cm from each
    other (a tree whose markers the cameras tell apart)."""
    out: list = []
    while len(out) < count:
        p = np.r_[rng.uniform(-0.08, 0.08, 2), rng.uniform(0.03, 0.08)]
        if np.hypot(*p[:2]) > 0.03 and all(np.linalg.norm(p - q) > 0.04 for q in out):
            out.append(p)
    return np.array(out)


def truth_beside(truth: SimTruth, path) -> SimTruth:
    """``truth`` with its true URDF named after the truth file ``path`` (``T.json`` ->
    ``T-true.urdf``), as :func:`drivers.sim.truth.save_truth` will write it."""
    return dataclasses.replace(truth, robot_file=f"{Path(path).stem}-true.urdf")


#: the tests' and the bench's simulated station: axes this many times the default
#: simulated station's speed (:data:`drivers.sim.serial_robot.VELOCITY`; acceleration
#: times its square), the snapshot's settle and sample period (s)
SPEED, SETTLE, PERIOD = 8.0, 0.01, 0.01


def urdf_config(truth: SimTruth, ref: str, folder, *, speed: float = SPEED,
                frames: int | None = None, settle: float | None = SETTLE,
                period: float | None = PERIOD, timeout: float | None = None) -> Path:
    """The simulated station of the URDF robot ``ref`` (:func:`drivers.robot_file.urdf_ref`)
    measured in ``truth``'s room, as ``folder/station.toml``: ``robot_file`` (absolute),
    ``base_link``, ``tip_link`` at top level, the default simulated station's devices
    (:func:`drivers.sim.serial_robot.sim_config_data`) with its axes ``speed`` times
    faster, the snapshot's ``settle`` and ``period`` (None: the default's), and the
    room's ``[mocap]`` (:func:`drivers.sim.mocap_room.room_section`) averaging ``frames``
    frames per reading and waiting ``timeout`` s for one (None: the room's)."""
    from drivers.robot_file import split_urdf_ref
    from drivers.sim.serial_robot import ACCELERATION, VELOCITY, sim_config_data

    path, base, tip = split_urdf_ref(ref)
    data = sim_config_data(load_robot_file(ref), velocity=VELOCITY * speed,
                           acceleration=ACCELERATION * speed * speed, truth=truth)
    for key, v in (("settle", settle), ("period", period)):
        if v is not None:
            data["snapshot"][key] = v
    for key, v in (("frames", frames), ("timeout", timeout)):
        if v is not None:
            data["mocap"][key] = v
    lines = [f"robot_file = {json.dumps(str(Path(path).resolve()))}",
             f"base_link = {json.dumps(base)}", f"tip_link = {json.dumps(tip)}"]

    def emit(prefix, table):
        lines.append(f"[{prefix}]")
        lines.extend(f"{k} = {json.dumps(v)}" for k, v in table.items() if not isinstance(v, dict))
        for k, v in table.items():
            if isinstance(v, dict):
                emit(f"{prefix}.{k}", v)

    for key in ("canopen", "inclinometer", "drawwire", "snapshot", "mocap"):
        emit(key, data[key])
    out = Path(folder) / "station.toml"
    out.write_text("\n".join(lines) + "\n")
    return out


def run_urdf_session(truth: SimTruth, ref: str, folder, *, seed: int = 0, request=None,
                     speed: float = SPEED, frames: int | None = None, count: int | None = None):
    """One unattended sm-markers session (:func:`station.simulation.sessions.
    simulated_session`) on the simulated ``truth`` of the URDF robot ``ref`` in ``folder``
    (its truth file and true URDF, its station config :func:`urdf_config`), scored
    against the truth at ``count`` poses (:func:`station.simulation.urdf_scores.
    score_document`): a :class:`~station.simulation.urdf_scores.UrdfScore`."""
    from station.planning.request import PlanRequest
    from station.simulation import urdf_scores
    from station.simulation.sessions import event_counts, simulated_session

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    truth = truth_beside(truth, folder / "truth.json")
    save_truth(truth, folder / "truth.json")
    cfg = urdf_config(truth, ref, folder, speed=speed, frames=frames)
    run = simulated_session(truth, folder, "sm-markers", request or PlanRequest(seed=seed),
                            cfg, seed, robot=ref)
    s = run.session
    score = urdf_scores.UrdfScore(seed=seed, completed=run.completed, error=run.error,
                                  refused=run.refused, poses=len(s.measured),
                                  skipped=len(s.skipped), events=event_counts(s),
                                  seconds=run.seconds)
    if run.completed:
        urdf_scores.score_document(score, s.outcome.document, truth,
                                   count=count or urdf_scores.COUNT)
    return score
