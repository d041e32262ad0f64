"""``python app.py accuracy``: pose accuracy and repeatability as ISO 9283 defines them,
measured at the station before and after the calibration (docs/accuracy.md).

The face of the test, as :mod:`station.headless` is the session's: with ``--simulate`` the
simulated devices run in their own process (``app.py simulate``, the truth file's
``repeatability`` in its drives); without it the devices come from ``--config``. The test
cube is found (or ``--cube`` checked) before the simulator starts or anything moves
(:mod:`station.planning.iso_cube`), the programs are run and measured
(:mod:`station.session.iso_run`), and the figures printed and written
(:mod:`station.outputs.iso9283`); the CSV is written atomically after the last cycle.
"""
from __future__ import annotations

import sys

import numpy as np

from calibration import iso9283
from calibration.errors import ConfigError
from station.outputs.iso9283 import (MAX_CYCLES, PROGRAMS, check_file, csv_text, parse_cube,
                                     results, summary, table)


def main(args) -> int:
    """The command (module doc)."""
    from drivers.atomic import check_outputs
    from drivers.config import load_station_config
    from drivers.endpoints import load_endpoints, with_endpoints
    from station.outputs.params_file import check_usable, read_params

    cycles = int(args.cycles)
    if not 2 <= cycles <= MAX_CYCLES:
        raise ConfigError(f"--cycles {cycles}: expected 2 to {MAX_CYCLES} (the standard's "
                          f"{iso9283.CYCLES})")
    cube_arg = parse_cube(getattr(args, "cube", None))
    check_outputs((args.out, "the accuracy CSV (--out)"),
                  inputs=tuple(p for p in (args.params, args.truth, args.config) if p))
    doc = read_params(args.params)
    check_usable(doc, args.params)
    check_file(doc, args.params)
    if args.simulate:
        from drivers.sim.server import SimulatorProcess, load_sim_config
        from station.simulation.simulated_station import simulated_station

        config = load_sim_config(args.robot, args.config, args.truth)
        plan = _plan(doc, args, config, cube_arg)
        _truth, seed, _rec = simulated_station(args.robot, args.truth,
                                               getattr(args, "sim_seed", None))
        print(f"starting the simulated {args.robot} (truth: {args.truth}; seed {seed}) ...",
              flush=True)
        with SimulatorProcess(args.robot, truth=args.truth, config=args.config,
                              seed=seed) as sim:
            return _measure(with_endpoints(config, sim.endpoints, source="simulator"), plan,
                            args, cycles)
    if not args.config:
        raise ConfigError("give --config FILE (the station's devices) or --simulate")
    config = load_station_config(args.config)
    if getattr(args, "endpoints", None):
        config = with_endpoints(config, load_endpoints(args.endpoints), source=args.endpoints)
    return _measure(config, _plan(doc, args, config, cube_arg), args, cycles)


def _plan(doc, args, config, cube_arg):
    """``(tm, cube, doc, names)``: the test model and its cube, printed."""
    from drivers.sim.urdf_truth import same_chain
    from station.outputs.compensate import setup
    from station.planning import iso_cube
    from station.session.marker_kind import sight_of

    if config.mocap is None:
        raise ConfigError("the accuracy test needs the station's point instrument: a [mocap] "
                          "section (docs/accuracy.md)", source=config.source, key="mocap")
    s = setup(doc, args.params)
    why = (same_chain(s.robot.spec, config.spec) if hasattr(config.spec, "base_link")
           else "the station's robot is not a URDF")
    if why:
        raise ConfigError(f"the parameter file's robot is not the station's: {why}",
                          source=args.params)
    tm = iso_cube.test_model(s, doc, sight_of(config.mocap), config.envelope.qm_range)
    rng = np.random.default_rng(int(getattr(args, "seed", 0) or 0))
    if cube_arg is None:
        print("finding the largest test cube the instrument sees ...", flush=True)
        cube = iso_cube.largest_cube(tm, rng)
    else:
        cube = iso_cube.given_cube(tm, cube_arg[0], cube_arg[1], rng)
    c = ", ".join(f"{v * 1e3:.1f}" for v in cube.centre)
    print(f"test cube: edge {cube.size * 1e3:.1f} mm about ({c}) mm in the base link frame "
          f"{s.robot.spec.base_link} (edges along its axes); measuring plane C1-C2-C7-C8, "
          "P1 its centre, P2..P5 at 10 % of the diagonal from C1, C2, C7, C8; the tool at "
          "one orientation throughout")
    print(f"the tool: {s.what}")
    return tm, cube, doc, s.names


def _measure(config, plan, args, cycles: int) -> int:
    from drivers.atomic import write_atomic
    from drivers.rig import Rig
    from station.planning.serial_plan import path_clear
    from station.session.iso_run import run_program

    tm, cube, doc, names = plan
    M = tm.points.shape[0]
    print(f"{cycles} cycles P1 P5 P4 P3 P2 of each program, every pose approached from the "
          "one before it: before = the nominal program (the nominal model's inverse "
          "kinematics), after = the compensated program (app.py compensate's)", flush=True)
    with Rig(config) as rig:
        here = np.asarray(rig.qm(), dtype=float)
        if not path_clear(tm.robot, tm.comp.xi_cal, here, cube.q_nom[1]):
            raise ConfigError("the way from where the robot stands to P2 comes near the floor: "
                              "jog the robot up, nearer the cube, and run the test again")
        readings = {prog: run_program(rig, config, cube.q_nom if prog == "nominal"
                                      else cube.q_comp, cycles, M, name=prog,
                                      progress=_progress)
                    for prog in PROGRAMS}
    write_atomic(args.out, csv_text(tm, cube, readings, names).encode("utf-8"))
    res = results(tm, cube, readings)
    cov = doc["covariance"]
    sp, _sa = tm.comp.predicted(cube.q_comp, list(cov["names"]),
                                np.asarray(cov["matrix"], dtype=float))
    predicted = float(np.sqrt(np.mean(sp ** 2))) if np.isfinite(sp).all() else None
    print("ISO 9283 pose accuracy AP and repeatability RP, position:")
    for line in table(res) + summary(res, cycles, predicted):
        print(line)
    print(f"every measured cycle written to {args.out}")
    return 0


def _progress(text: str) -> None:
    print(text, file=sys.stdout, flush=True)
