"""The simulated station as one process: ``python app.py simulate --robot R``.

:func:`main` builds the simulated station (:class:`~drivers.sim.sim_station.SimStation`:
the simulated robot behind its devices, each speaking its real wire protocol) from its
truth file and station config (``--truth``, ``--config``; defaults the fixtures,
:mod:`drivers.sim.station_files`), starts it and runs until SIGINT/SIGTERM (or, with
``--exit-with-parent``, until the process that started it ends). The endpoints (cli.md)
are printed as one JSON line and, with ``--endpoints FILE``, written atomically to that
file (removed again when the simulator stops); they include ``control``, a JSON-lines
TCP port through which tests and demos inject faults and look at the simulated truth
(:mod:`drivers.sim.control`; its commands are
:meth:`~drivers.sim.sim_station.SimStation.command`'s).

The simulator's public names are importable from here: :class:`SimStation`,
:class:`SimControl` (the control port's client), :class:`SimulatorProcess` (this command
in a child process, :mod:`drivers.sim.simulator_process`), :func:`build`,
:func:`truth_of`, :func:`load_sim_config` and the fixtures' default paths.
"""
from __future__ import annotations

import argparse
import json
import os
import signal
import sys
import threading
from pathlib import Path

from calibration.errors import ConfigError
from drivers.atomic import write_atomic
from drivers.sim.control import SimControl
from drivers.sim.serial_robot import is_robot_file
from drivers.sim.sim_station import SimStation
from drivers.sim.simulator_process import SimulatorFailed, SimulatorProcess
from drivers.sim.station_files import (build, default_config_path, default_truth_path,
                                       load_sim_config, truth_of)
from drivers.sim.truth import report_truth

__all__ = ["SimStation", "SimControl", "SimulatorFailed", "SimulatorProcess", "build",
           "default_config_path", "default_truth_path", "load_sim_config", "main",
           "report_truth", "truth_of", "write_endpoints"]


def write_endpoints(path: str | Path, endpoints: dict) -> None:
    """Write the endpoints JSON atomically (a reader never sees half a file)."""
    write_atomic(Path(path), (json.dumps(endpoints, indent=2) + "\n").encode())


def main(args: argparse.Namespace) -> int:
    """``app.py simulate``: start, print endpoints, run until SIGINT/SIGTERM."""
    if args.endpoints is not None:     # before the devices start: never over an input
        from drivers.atomic import check_outputs

        check_outputs((args.endpoints, "the endpoints file (--endpoints)"),
                      inputs=tuple(p for p in (args.truth, args.config,
                                               args.robot if is_robot_file(args.robot)
                                               else None) if p))
    station = build(args.robot, args.truth, args.config, seed=getattr(args, "seed", None),
                    pose_noise=getattr(args, "pose_noise", False))
    stop = threading.Event()
    parent = os.getppid() if getattr(args, "exit_with_parent", False) else None

    def on_signal(signum, frame):
        stop.set()

    old = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        with station:
            ep = station.endpoints
            if args.endpoints:
                try:
                    write_endpoints(args.endpoints, ep)
                except OSError as e:
                    raise ConfigError(f"--endpoints {args.endpoints}: cannot write: "
                                      f"{e.strerror or e}") from None
            print(json.dumps(ep), flush=True)
            print(f"simulated {args.robot} running (truth: {station.truth.source or 'report'}); "
                  f"CANopen socketcand {ep['canopen']['host']}:{ep['canopen']['port']}, "
                  f"inclinometer {ep.get('inclinometer', {}).get('port')}, draw-wire Modbus TCP "
                  f"{ep.get('drawwire', {}).get('port')}; Ctrl-C stops", file=sys.stderr,
                  flush=True)
            while not stop.wait(0.2):
                if parent is not None and os.getppid() != parent:
                    break       # the station that started us died (even by SIGKILL)
    finally:
        for s, h in old.items():
            signal.signal(s, h)
        if args.endpoints:
            Path(args.endpoints).unlink(missing_ok=True)
    return 0
