"""``python app.py run --simulate --robot R --method M [--truth FILE] --out DIR``.

A whole station session without a GUI: with ``--simulate`` the simulated devices
run in their own process (``app.py simulate``), exactly as a separate
simulator would; without it the devices come from ``--config``. Progress
(pose i of m, the current readings) goes to the terminal. Running the same
command again on the same ``--out`` folder resumes a session that was killed.

Guided touching (sm-plane, sm-self-redundancy) needs an operator: with
``--simulate`` a simulated one (:mod:`station.simulation.touch_operator`) touches through the
simulator's control port, and the values the report takes as known (sm-plane:
``L4, theta0, a0`` and the plane; sm-self-redundancy: ``L4``) are read from the
simulator's truth file as the engineer's measurements, unless ``--nominal`` gives
them; the run says so. Without ``--simulate`` these methods are refused.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import shlex
import sys
import warnings
from pathlib import Path

from calibration.errors import ConfigError
from drivers.config import load_station_config
from drivers.endpoints import load_endpoints, with_endpoints
from station.planning.request import TOUCH_METHODS, PlanRequest
from station.session.session import Session
from station.session.execution import Progress
from station.outputs.units import MM_DEG


class TerminalProgress:
    """Observer printing progress: one updating line on a terminal, one line per pose
    otherwise (logs, CI). Readings in the display units (:mod:`station.outputs.units`), but
    the channels in ``hidden`` (a reading the method does not use)."""

    def __init__(self, stream=None, units=MM_DEG, hidden=()):
        self.stream = stream or sys.stdout
        self.tty = self.stream.isatty()
        self.units = units
        self.hidden = set(hidden)
        self._open_line = False

    def shown(self, name: str) -> bool:
        return name not in self.hidden

    def __call__(self, kind: str, payload) -> None:
        if kind == "progress" and isinstance(payload, Progress):
            if not payload.readings:
                if self.tty:
                    self._line(f"{payload.label(current=True)}: {payload.message}")
                return
            text = ", ".join(self.units.channel(k, v, ".5g")
                             for k, v in payload.readings.items() if self.shown(k))
            verb = "touched" if "touched" in payload.message else "recorded"
            self._line(f"{payload.label()} {verb}: {text}", final=True)
        elif kind == "event" and payload.get("kind") not in ("plan",):
            self._line(f"[{payload['kind']}] {payload['message']}", final=True)
        elif kind == "event":
            self._line(payload["message"], final=True)

    def _line(self, text: str, final: bool = False) -> None:
        if self.tty:
            self.stream.write("\r\033[K" + text + ("\n" if final else ""))
        else:
            if not final:
                return
            self.stream.write(text + "\n")
        self.stream.flush()


def main(args: argparse.Namespace) -> int:
    from drivers.atomic import check_output_folder
    from drivers.sim.serial_robot import is_robot_file
    from station.session.folder import PARAMS, REPORT, TRACE, URDF

    check_output_folder(args.out, "the session folder (--out)", (TRACE, PARAMS, REPORT, URDF),
                        inputs=tuple(p for p in (args.robot if is_robot_file(args.robot)
                                                 else None, args.truth, args.config,
                                                 getattr(args, "endpoints", None)) if p))
    out = Path(args.out)
    accept = bool(getattr(args, "accept_poor_fit", False))
    request = PlanRequest(count=getattr(args, "count", None), seed=getattr(args, "seed", 0) or 0,
                          design=getattr(args, "design", None) or "optimal",
                          target=parse_target(getattr(args, "target_std", None)),
                          grow=not getattr(args, "one_shot", False))
    nominal = {}
    for item in getattr(args, "nominal", None) or ():
        name, eq, value = item.partition("=")
        try:
            nominal[name.strip()] = float(value)
        except ValueError:
            raise ConfigError(f"--nominal {item!r}: expected NAME=VALUE with a number") from None
    if args.simulate:
        from drivers.sim.serial_robot import is_robot_file
        from drivers.sim.server import SimulatorProcess, load_sim_config
        from station.simulation.simulated_station import (engineer_measurements,
                                                          simulated_station)

        config = load_sim_config(args.robot, args.config, args.truth)
        if not is_robot_file(args.robot) and config.robot != args.robot:
            raise ConfigError(f"the station config is for {config.robot}, not {args.robot}",
                              source=config.source, key="robot")
        measured = {}
        if args.method in TOUCH_METHODS:
            measured = engineer_measurements(args.robot, args.method, args.truth, nominal)
        truth, seed, record = simulated_station(args.robot, args.truth,
                                                getattr(args, "sim_seed", None))
        print(f"starting the simulated {args.robot} (truth: {truth}; seed {seed}, readings "
              "repeatable: the same command gives the same values; --sim-seed N for other "
              "noise) ...", flush=True)
        with SimulatorProcess(args.robot, truth=args.truth, config=args.config,
                              seed=seed, pose_noise=True) as sim:
            config = with_endpoints(config, sim.endpoints, source="simulator")
            if args.method not in TOUCH_METHODS:
                return _run(config, args.method, out, request, nominal, station=record,
                            accept=accept)
            from station.simulation.touch_operator import SimulatedOperator

            with sim.control() as control:
                return _run(config, args.method, out, request, {**nominal, **measured},
                            touch=SimulatedOperator(control), measured=measured,
                            station=record, accept=accept)
    if args.method in TOUCH_METHODS:
        raise ConfigError(f"{args.method} is measured by guided touching, and a headless run "
                          "has no operator to bring the tool into contact: use --simulate "
                          "(a simulated operator), or a program that gives the session a "
                          "touch callback")
    if not args.config:
        raise ConfigError("give --config FILE (the station's devices) or --simulate")
    config = load_station_config(args.config)
    want = getattr(args, "robot", None)
    from drivers.robot_file import is_robot_file

    if want and is_robot_file(want):   # a robot file or a URDF robot: its checksum and chain
        from drivers.config import check_config_robot

        check_config_robot(config, want)
    elif want and not _same_robot(want, config.robot):
        raise ConfigError(f"the station config is for {config.robot}, not {want} (--robot): "
                          "give the config of this robot's station, or leave --robot out",
                          source=config.source, key="robot")
    if getattr(args, "endpoints", None):
        config = with_endpoints(config, load_endpoints(args.endpoints), source=args.endpoints)
    return _run(config, args.method, out, request, nominal, accept=accept)


def _same_robot(a: str, b: str) -> bool:
    """Do ``--robot`` and a config's ``robot`` name the same robot (a built-in's name, or
    the same robot file by path)?"""
    if a == b:
        return True
    try:
        return os.path.isfile(a) and os.path.isfile(b) and os.path.samefile(a, b)
    except OSError:
        return False


def parse_target(text: str | None) -> tuple[str, float] | None:
    """``--target-std``: ``STD`` (the tool's held-out error) or ``NAME=STD``."""
    if not text:
        return None
    name, eq, value = text.rpartition("=")
    try:
        std = float(value)
    except ValueError:
        std = math.nan
    if not (math.isfinite(std) and std > 0) or (eq and not name.strip()):
        raise ConfigError(f"--target-std {text!r}: expected STD or NAME=STD with a number > 0, "
                          f"e.g. 5e-5 (m) or k1=1e-6")
    return (name.strip() if eq else "heldout", std)


def _run(config, method: str, out: Path, request: PlanRequest, nominal: dict, *,
         touch=None, measured: dict | None = None, station: dict | None = None,
         accept: bool = False) -> int:
    from calibration.methods import METHODS
    from station.outputs.units import from_config

    units = from_config(config)
    # the wrist's station may have a draw-wire: its distance means nothing to pm-*
    hide = set() if "distance" in METHODS[method].channels else {"distance"}
    progress = TerminalProgress(units=units, hidden=hide)
    try:
        return _session(config, method, out, request, nominal, touch, measured, station,
                        progress, units, accept)
    except KeyboardInterrupt:
        kept = _recorded_poses(out / "trace.jsonl")
        print(file=sys.stderr)
        raise KeyboardInterrupt(f"interrupted: {kept} poses recorded in {out / 'trace.jsonl'} "
                                f"are kept; resume with: {resume_command()}") from None


def resume_command() -> str:
    """The command line that was run (the same command resumes the session)."""
    argv = list(sys.argv)
    if argv and argv[0].endswith("app.py"):
        argv = ["python", argv[0]] + argv[1:]
    return shlex.join(argv)


def _recorded_poses(path: Path) -> int:
    n = 0
    try:
        with open(path, encoding="utf-8") as f:
            for line in f:
                try:
                    n += json.loads(line).get("record") == "pose"
                except ValueError:
                    continue
    except OSError:
        return 0
    return n


def _session(config, method, out, request, nominal, touch, measured, station, progress,
             units, accept=False) -> int:
    from station.fitting.batch import ConditioningWarning
    from station.outputs.fit_summary import format_table

    with Session(config, method, out, request=request, observer=progress,
                 nominal=nominal, touch=touch, station=station,
                 accept_poor_fit=accept) as s:
        if s.finished:
            print(f"the session in {out} is finished ({len(s.measured)} poses recorded and "
                  "exported): its result again; the files are left as they are", flush=True)
        elif s.resumed:
            print(f"resuming the session in {out} ({len(s.measured)} poses recorded)",
                  flush=True)
        elif measured:
            print("known start values (not identifiable by " + method + ", they influence "
                  "the result), taken from the simulator's truth file as if the engineer had "
                  "measured them: " + ", ".join(f"{k} {v:.6g}" for k, v in measured.items()),
                  flush=True)
        if touch is not None:
            print("guided touching by the simulated operator (it watches the contact through "
                  "the simulator's control port)", flush=True)
        with warnings.catch_warnings():
            # said once, as the table's note (station.outputs.fit_summary.format_table)
            warnings.simplefilter("ignore", ConditioningWarning)
            files = s.run()
        print()
        print(format_table(s.outcome))
        held = "pairs" if method == "sm-self-redundancy" else "poses"
        said = set()
        for v in s.validation or ():
            note = v.get("note")
            if v["rms_before"] is None and note and note not in said:
                print(f"validation: no RMS before calibration: {note}")
                said.add(note)
            pts = v.get("points")      # points on the tool: their 3D errors, per point
            if pts is not None:
                before = ("n/a" if pts.get("rms_before") is None
                          else units.text(pts["rms_before"], v["unit"]))
                print(f"validation {v['channel']}: points' 3D RMS {before} -> "
                      f"{units.text(pts['rms_after'], v['unit'])} over {pts['n']} held-out "
                      f"points of {pts['poses']} {held}")
                continue
            before = ("n/a" if v["rms_before"] is None
                      else units.text(v["rms_before"], v["unit"]))
            print(f"validation {v['channel']}: RMS {before} -> "
                  f"{units.text(v['rms_after'], v['unit'])} over {v['n']} held-out {held}")
        print(f"trace {files['trace']}\nparameter file {files['params']} ({files['checksum']})\n"
              f"report {files['report']}")
        if files.get("urdf"):
            print(f"URDF {files['urdf']}")
    return 0
