"""``python app.py accuracy``: pose accuracy and repeatability as ISO 9283 defines them,
measured at the station before and after the calibration (docs/accuracy.md).

The face of the test, as :mod:`station.headless` is the session's: with ``--simulate`` the
simulated devices run in their own process (``app.py simulate``, the truth file's
``repeatability`` in its drives); without it the devices come from ``--config``. The test
cube is found (or ``--cube`` checked) before the simulator starts or anything moves, the
programs are run and measured, the CSV written atomically after the last cycle, and the
figures printed and the test's HTML page written from it (:mod:`station.session.iso_test`;
the page: :mod:`station.outputs.iso9283_page`). ``--csv`` instead writes the page again
from a measured CSV and its parameter file, nothing moving.
"""
from __future__ import annotations

import sys
from pathlib import Path

from calibration import iso9283
from calibration.errors import ConfigError
from station.outputs.iso9283 import MAX_CYCLES, check_file, parse_cube, summary, table


def main(args) -> int:
    """The command (module doc)."""
    from drivers.atomic import check_outputs
    from drivers.config import load_station_config
    from drivers.endpoints import load_endpoints, with_endpoints
    from station.outputs.params_file import check_usable, read_params
    from station.session import iso_test

    if getattr(args, "csv", None):
        return _rebuild(args)
    if not args.robot or not args.out:
        raise ConfigError("give --robot ARM.urdf (with --base-link, --tip-link) and --out "
                          "ACCURACY.csv to run the test, or --csv ACCURACY.csv to write its "
                          "page again from a measured CSV")
    cycles = int(args.cycles)
    if not 2 <= cycles <= MAX_CYCLES:
        raise ConfigError(f"--cycles {cycles}: expected 2 to {MAX_CYCLES} (the standard's "
                          f"{iso9283.CYCLES})")
    cube_arg = parse_cube(getattr(args, "cube", None))
    page = _page(args, args.out)
    check_outputs((args.out, "the accuracy CSV (--out)"), (page, "the test's page (--report)"),
                  inputs=_inputs(args))
    doc = read_params(args.params)
    check_usable(doc, args.params)
    check_file(doc, args.params)
    if args.simulate:
        from drivers.sim.server import SimulatorProcess, load_sim_config
        from station.simulation.simulated_station import simulated_station

        config = load_sim_config(args.robot, args.config, args.truth)
        plan = iso_test.plan(doc, args.params, config, cube_arg, args.seed, _say)
        _truth, seed, _rec = simulated_station(args.robot, args.truth,
                                               getattr(args, "sim_seed", None))
        _say(f"starting the simulated {args.robot} (truth: {args.truth}; seed {seed}) ...")
        with SimulatorProcess(args.robot, truth=args.truth, config=args.config,
                              seed=seed) as sim:
            return _measure(with_endpoints(config, sim.endpoints, source="simulator"), plan,
                            args, cycles, page)
    if not args.config:
        raise ConfigError("give --config FILE (the station's devices) or --simulate")
    config = load_station_config(args.config)
    if getattr(args, "endpoints", None):
        config = with_endpoints(config, load_endpoints(args.endpoints), source=args.endpoints)
    plan = iso_test.plan(doc, args.params, config, cube_arg, args.seed, _say)
    return _measure(config, plan, args, cycles, page)


def _page(args, csv_path) -> str:
    """``--report``, or the CSV's name with ``.html`` beside it."""
    return getattr(args, "report", None) or str(Path(csv_path).with_suffix(".html"))


def _inputs(args) -> tuple:
    """The files read (the session's report beside the parameter file too: it is added
    to, never overwritten by the page)."""
    from station.session.iso_test import report_beside

    report = report_beside(args.params)
    return tuple(str(p) for p in (args.params, getattr(args, "truth", None),
                                  getattr(args, "config", None), getattr(args, "csv", None),
                                  report) if p)


def _measure(config, plan, args, cycles: int, page: str) -> int:
    from drivers.rig import Rig
    from station.session import iso_test

    with Rig(config) as rig:
        readings = iso_test.measure(rig, config, plan, cycles, say=_say)
    figures = iso_test.write(plan, readings, args.out, None, _say)
    _print(figures)
    iso_test.publish(figures, page, _say)
    return 0


def _rebuild(args) -> int:
    """``--csv``: the page written again from the CSV and the parameter file."""
    from drivers.atomic import check_outputs
    from station.outputs import iso9283_csv
    from station.session import iso_test

    if args.out:
        raise ConfigError("--out goes with a test that measures; with --csv the page is "
                          "written again (--report)")
    page = _page(args, args.csv)
    check_outputs((page, "the test's page (--report)"), inputs=_inputs(args))
    figures = iso9283_csv.read(args.csv, args.params)
    _print(figures)
    iso_test.publish(figures, page, _say)
    return 0


def _print(figures) -> None:
    _say("ISO 9283 pose accuracy AP and repeatability RP, position:")
    for line in table(figures.res) + summary(figures.res, figures.cycles,
                                             figures.predicted_rms):
        _say(line)


def _say(text: str) -> None:
    print(text, file=sys.stdout, flush=True)
