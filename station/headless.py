"""``python app.py run --simulate --robot R --method M [--truth FILE] --out DIR``.

A whole station session without a GUI: with ``--simulate`` the simulated devices
run in their own process (``app.py simulate``), exactly as a separate
simulator would; without it the devices come from ``--config``. Progress
(pose i of m, the current readings) goes to the terminal. Running the same
command again on the same ``--out`` folder resumes a session that was killed.

Guided touching (sm-plane, sm-self-redundancy) needs an operator: with
``--simulate`` a simulated one (:mod:`station.sim_operator`) touches through the
simulator's control port, and the values the report takes as known (sm-plane:
``L4, theta0, a0`` and the plane; sm-self-redundancy: ``L4``) are read from the
simulator's truth file as the engineer's measurements, unless ``--nominal`` gives
them; the run says so. Without ``--simulate`` these methods are refused.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from calibration.errors import ConfigError
from drivers.config import load_station_config
from drivers.endpoints import load_endpoints, with_endpoints
from station.planner import MUST_KNOW, TOUCH_METHODS, PlanRequest
from station.session import Progress, Session


class TerminalProgress:
    """Observer printing progress: one updating line on a terminal, one line per pose
    otherwise (logs, CI)."""

    def __init__(self, stream=None):
        self.stream = stream or sys.stdout
        self.tty = self.stream.isatty()
        self._open_line = False

    def __call__(self, kind: str, payload) -> None:
        if kind == "progress" and isinstance(payload, Progress):
            if not payload.readings:
                if self.tty:
                    self._line(f"pose {payload.done + 1} of {payload.total}: {payload.message}")
                return
            text = ", ".join(f"{k} {v:.5g}" for k, v in payload.readings.items())
            verb = "touched" if "touched" in payload.message else "recorded"
            self._line(f"pose {payload.done} of {payload.total} {verb}: {text}", final=True)
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
    out = Path(args.out)
    request = PlanRequest(count=getattr(args, "count", None), seed=getattr(args, "seed", 0) or 0)
    nominal = {}
    for item in getattr(args, "nominal", None) or ():
        name, eq, value = item.partition("=")
        try:
            nominal[name.strip()] = float(value)
        except ValueError:
            raise ConfigError(f"--nominal {item!r}: expected NAME=VALUE with a number") from None
    if args.simulate:
        from drivers.sim.server import SimulatorProcess, default_config_path

        cfg_path = args.config or default_config_path(args.robot)
        config = load_station_config(cfg_path)
        if config.robot != args.robot:
            raise ConfigError(f"the station config is for {config.robot}, not {args.robot}",
                              source=str(cfg_path), key="robot")
        measured = {}
        if args.method in TOUCH_METHODS:
            measured = engineer_measurements(args.robot, args.method, args.truth, nominal)
        print(f"starting the simulated {args.robot} (truth: {args.truth or 'fixtures'}) ...",
              flush=True)
        with SimulatorProcess(args.robot, truth=args.truth, config=args.config,
                              seed=getattr(args, "sim_seed", None)) as sim:
            config = with_endpoints(config, sim.endpoints, source="simulator")
            if args.method not in TOUCH_METHODS:
                return _run(config, args.method, out, request, nominal)
            from station.sim_operator import SimulatedOperator

            with sim.control() as control:
                return _run(config, args.method, out, request, {**nominal, **measured},
                            touch=SimulatedOperator(control), measured=measured)
    if args.method in TOUCH_METHODS:
        raise ConfigError(f"{args.method} is measured by guided touching, and a headless run "
                          "has no operator to bring the tool into contact: use --simulate "
                          "(a simulated operator), or a program that gives the session a "
                          "touch callback")
    if not args.config:
        raise ConfigError("give --config FILE (the station's devices) or --simulate")
    config = load_station_config(args.config)
    if getattr(args, "endpoints", None):
        config = with_endpoints(config, load_endpoints(args.endpoints), source=args.endpoints)
    return _run(config, args.method, out, request, nominal)


def engineer_measurements(robot: str, method: str, truth: str | None, given: dict) -> dict:
    """Simulated station: the values an engineer measures before a guided-touching
    session (:data:`station.planner.MUST_KNOW`), read from the simulator's truth file;
    those ``given`` (``--nominal``) are kept."""
    from drivers.sim.server import default_truth_path
    from drivers.sim.truth import load_truth

    t = load_truth(truth or default_truth_path(robot))
    values = dict(t.parameters)
    if t.plane is not None:
        values.update(zip(("plane_a", "plane_b", "plane_c"), t.plane))
    missing = [k for k in MUST_KNOW[method] if k not in given and k not in values]
    if missing:
        raise ConfigError(f"{method} needs {', '.join(missing)}: the truth file gives none; "
                          f"give them with --nominal NAME=VALUE", source=t.source)
    return {k: float(values[k]) for k in MUST_KNOW[method] if k not in given}


def _run(config, method: str, out: Path, request: PlanRequest, nominal: dict, *,
         touch=None, measured: dict | None = None) -> int:
    from station.batch import format_table

    progress = TerminalProgress()
    with Session(config, method, out, request=request, observer=progress,
                 nominal=nominal, touch=touch) as s:
        if s.resumed:
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
        files = s.run()
        print()
        print(format_table(s.outcome))
        held = "pairs" if method == "sm-self-redundancy" else "poses"
        for v in s.validation or ():
            before = "n/a" if v["rms_before"] is None else f"{v['rms_before']:.4g}"
            print(f"validation {v['channel']}: RMS {before} -> {v['rms_after']:.4g} {v['unit']} "
                  f"over {v['n']} held-out {held}")
        print(f"trace {files['trace']}\nparameter file {files['params']} ({files['checksum']})\n"
              f"report {files['report']}")
    return 0
