"""The ISO 9283 accuracy test at the station, as ``app.py accuracy`` and the wizard's
Accuracy step both run it (docs/accuracy.md): the test cube planned for a parameter
file (:func:`plan`), both programs' cycles measured (:func:`measure`,
:mod:`station.session.iso_run`), and the CSV, the page and the report's link written
(:func:`write`). What is said along the way goes to ``say`` (the command prints it, the
wizard shows it).
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from calibration.errors import ConfigError
from station.outputs.iso9283 import PROGRAMS, check_file, csv_text
from station.session.folder import REPORT
from station.session.iso_run import run_program

Say = Callable[[str], None]


@dataclass
class Plan:
    """The test of one parameter file at one station: its test model and cube
    (:mod:`station.planning.iso_cube`), the file's content and path, the joints' names."""

    tm: object
    cube: object
    doc: dict
    params: str
    names: tuple


def plan(doc: dict, params: str, config, cube_arg=None, seed: int = 0,
         say: Say = print) -> Plan:
    """The test model of the parameter file ``params`` (its content ``doc``: a URDF
    robot's sm-markers calibration, else ConfigError) at the station ``config`` and its cube: the largest that fits, or ``cube_arg`` ``(centre
    m, size m)`` checked; said."""
    from drivers.sim.urdf_truth import same_chain
    from station.outputs.compensate import setup
    from station.planning import iso_cube
    from station.session.marker_kind import sight_of

    check_file(doc, params)
    if config.mocap is None:
        raise ConfigError("the accuracy test needs the station's point instrument: a [mocap] "
                          "section (docs/accuracy.md)", source=config.source, key="mocap")
    s = setup(doc, params)
    why = (same_chain(s.robot.spec, config.spec) if hasattr(config.spec, "base_link")
           else "the station's robot is not a URDF")
    if why:
        raise ConfigError(f"the parameter file's robot is not the station's: {why}",
                          source=params)
    tm = iso_cube.test_model(s, doc, sight_of(config.mocap), config.envelope.qm_range)
    rng = np.random.default_rng(int(seed or 0))
    if cube_arg is None:
        say("finding the largest test cube the instrument sees ...")
        cube = iso_cube.largest_cube(tm, rng)
    else:
        cube = iso_cube.given_cube(tm, cube_arg[0], cube_arg[1], rng)
    c = ", ".join(f"{v * 1e3:.1f}" for v in cube.centre)
    say(f"test cube: edge {cube.size * 1e3:.1f} mm about ({c}) mm in the base link frame "
        f"{s.robot.spec.base_link} (edges along its axes); measuring plane C1-C2-C7-C8, "
        "P1 its centre, P2..P5 at 10 % of the diagonal from C1, C2, C7, C8; the tool at "
        "one orientation throughout")
    say(f"the tool: {s.what}")
    return Plan(tm, cube, doc, str(params), tuple(s.names))


def measure(rig, config, p: Plan, cycles: int, *, say: Say = print, on_pose=None,
            stop=None, fault_policy=None) -> dict:
    """program -> :class:`~station.session.iso_run.Readings`: ``cycles`` cycles of the
    nominal program, then of the compensated one, at the robot of ``rig``."""
    from station.planning.serial_plan import path_clear

    tm, cube = p.tm, p.cube
    say(f"{cycles} cycles P1 P5 P4 P3 P2 of each program, every pose approached from the "
        "one before it: before = the nominal program (the nominal model's inverse "
        "kinematics), after = the compensated program (app.py compensate's)")
    here = np.asarray(rig.qm(), dtype=float)
    if not path_clear(tm.robot, tm.comp.xi_cal, here, cube.q_nom[1]):
        raise ConfigError("the way from where the robot stands to P2 comes near the floor: "
                          "jog the robot up, nearer the cube, and run the test again")
    return {prog: run_program(rig, config, cube.q_nom if prog == "nominal" else cube.q_comp,
                              cycles, tm.points.shape[0], name=prog, progress=say,
                              on_pose=on_pose, stop=stop, fault_policy=fault_policy)
            for prog in PROGRAMS}


def report_beside(params) -> Path | None:
    """The session's report beside the parameter file ``params``, where there is one."""
    path = Path(params).parent / REPORT
    return path if path.is_file() else None


def write(p: Plan, readings: dict, out, page, say: Say = print):
    """Write the CSV ``out`` (every measured cycle), then the page ``page`` rebuilt from it
    (None: none), then link the page from the session's report beside the parameter file
    (:func:`station.outputs.iso9283_page.link_report`); returns the
    :class:`~station.outputs.iso9283_csv.Figures`. The CSV first: the measurements are
    kept whatever comes after."""
    from drivers.atomic import write_atomic
    from station.outputs import iso9283_csv

    text = csv_text(p.tm, p.cube, readings, p.names)
    write_atomic(out, text.encode("utf-8"))
    say(f"every measured cycle written to {out}")
    figures = iso9283_csv.read(out, p.params, text=text, doc=p.doc)
    if page is not None:
        publish(figures, page, say)
    return figures


def publish(figures, page, say: Say = print) -> None:
    """The page of ``figures`` written to ``page`` and linked from the session's report."""
    from station.outputs import iso9283_page

    iso9283_page.write(page, figures)
    say(f"the test's page written to {page}")
    report = report_beside(figures.params_path)
    if report is not None:
        say(f"the page: {iso9283_page.link_report(report, page, figures)}")
