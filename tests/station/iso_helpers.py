"""What the accuracy tests share: a URDF arm calibrated from a trace of its simulated truth
(the station's session is tested elsewhere; here its result is what matters), and an
ISO 9283 test of it made up without devices (the readings where the calibrated model
puts the points on the tool, plus the instrument's noise), for the page's and the
wizard's fast tests."""
from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from calibration.robots import get_robot
from drivers.config_reader import frozen_map
from drivers.robot_file import robot_ref
from drivers.sim.truth import load_truth, save_truth
from drivers.urdf_file import load_urdf
from station.fitting.batch import calibrate_trace
from station.simulation import tracegen_urdf as tg
from station.simulation.urdf_sessions import truth_beside, urdf_config, urdf_truth
from tests.station.urdf_helpers import URDF

SEED = 7
#: a few arc-seconds of backlash, a couple of random positioning error per move
REPEATABILITY = {"backlash": (2e-5,) * 6, "positioning": (1e-5,) * 6}


def calibrate(folder: Path, seed: int = SEED, draw: int = SEED, *, params: str = "p.json",
              repeatability=REPEATABILITY, **config) -> Path:
    """In ``folder``: ``truth.json`` (the arm drawn with ``seed``, ``repeatability`` in its
    drives), ``station.toml`` (its station, ``config`` passed on) and ``params``, a
    calibration of a 60-pose trace of the true robot (poses drawn with ``draw``) seen by
    the truth's motion capture (0.03 mm per coordinate). Returns the folder."""
    from station.recording.import_markers import start_values
    from station.recording.trace_writer import write_trace

    folder.mkdir(parents=True, exist_ok=True)
    ref = robot_ref(str(URDF), "base_link", "tool0")
    truth, x = urdf_truth(ref, seed, "the accuracy test's arm")
    if repeatability:
        truth = dataclasses.replace(truth, repeatability=frozen_map(repeatability))
    save_truth(truth_beside(truth, folder / "truth.json"), folder / "truth.json")
    urdf_config(load_truth(folder / "truth.json"), ref, folder, **config)
    robot = get_robot(load_urdf(URDF, "base_link", "tool0"))
    rng = np.random.default_rng(draw)
    qm = tg.draw_poses(robot, 60, rng)
    P = tg.readings(robot, x, np.asarray(truth.points), qm, rng, 3e-5)
    header = {"robot": robot.name, "robot_file": dict(robot.spec.source), "method": "sm-markers",
              "markers": len(truth.points), "nominal": start_values(robot, qm, P, "t.jsonl"),
              "sigma": {"marker": 3e-5}, "station": {"joints": list(robot.spec.joint_names)}}
    poses = [{"index": i, "qm": [float(v) for v in q],
              "markers": [[float(c) for c in p] for p in P[i]]} for i, q in enumerate(qm)]
    write_trace(folder / "t.jsonl", header, None, poses)
    calibrate_trace(str(folder / "t.jsonl"), out=str(folder / params))
    return folder


def made_up_test(folder: Path, cycles: int = 4, seed: int = 3, params: str = "p.json",
                 size: float = 0.2, unseen=(("nominal", 2, "P3"),)):
    """``(plan, readings)``: a test cube of edge ``size`` that fits (the first of the
    candidates of :mod:`station.planning.iso_cube`), and ``cycles`` cycles of each
    program read where the calibrated model puts the points on the tool, with 0.03 mm of
    noise per coordinate; a point not seen at each ``(program, cycle, pose)`` of
    ``unseen``."""
    from calibration import iso9283
    from drivers.config import load_station_config
    from station.outputs.compensate import setup
    from station.outputs.iso9283 import PROGRAMS
    from station.outputs.params_file import read_params
    from station.planning import iso_cube
    from station.session.iso_run import Readings
    from station.session.iso_test import Plan
    from station.session.marker_kind import sight_of

    config = load_station_config(folder / "station.toml")
    path = str(folder / params)
    doc = read_params(path)
    s = setup(doc, path)
    tm = iso_cube.test_model(s, doc, sight_of(config.mocap), config.envelope.qm_range)
    qs, Ts = iso_cube.candidates(tm, np.random.default_rng(0), 12)
    cube = next(c for c in (iso_cube.fit_cube(tm, T[:3, 3], size, T[:3, :3], q)
                            for q, T in zip(qs, Ts)) if not isinstance(c, str))
    rng = np.random.default_rng(seed)
    readings = {}
    for prog in PROGRAMS:
        q = cube.q_nom if prog == "nominal" else cube.q_comp
        F = tm.robot.frames(q, tm.x_view)                 # the tip link, instrument frame
        true = np.einsum("kij,mj->kmi", F[:, :3, :3], tm.points) + F[:, None, :3, 3]
        points = true[None] + rng.normal(0.0, 3e-5, (cycles, *true.shape))
        qm = np.broadcast_to(q, (cycles, *q.shape)).copy()
        t = [[f"2026-01-01T10:{c:02d}:{k:02d}.000+00:00" for k in range(5)]
             for c in range(cycles)]
        readings[prog] = Readings(points, qm, t)
    for prog, c, pose in unseen:
        readings[prog].points[c - 1, iso9283.POINTS.index(pose), 0] = np.nan
    return Plan(tm, cube, doc, path, tuple(s.names)), readings
