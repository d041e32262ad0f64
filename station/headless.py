"""``python app.py run --simulate --robot R --method M [--truth FILE] --out DIR``.

A whole station session without a GUI: with ``--simulate`` the simulated devices
run in their own process (``app.py simulate``), exactly as a separate
simulator would; without it the devices come from ``--config``. Progress
(pose i of m, the current readings) goes to the terminal. Running the same
command again on the same ``--out`` folder resumes a session that was killed.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from calibration.errors import ConfigError
from drivers.config import load_endpoints, load_station_config, with_endpoints
from station.planner import PlanRequest
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
            self._line(f"pose {payload.done} of {payload.total} recorded: {text}", final=True)
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
        print(f"starting the simulated {args.robot} (truth: {args.truth or 'fixtures'}) ...",
              flush=True)
        with SimulatorProcess(args.robot, truth=args.truth, config=args.config,
                              seed=getattr(args, "sim_seed", None)) as sim:
            config = with_endpoints(config, sim.endpoints, source="simulator")
            return _run(config, args.method, out, request, nominal)
    if not args.config:
        raise ConfigError("give --config FILE (the station's devices) or --simulate")
    config = load_station_config(args.config)
    if getattr(args, "endpoints", None):
        config = with_endpoints(config, load_endpoints(args.endpoints), source=args.endpoints)
    return _run(config, args.method, out, request, nominal)


def _run(config, method: str, out: Path, request: PlanRequest, nominal: dict) -> int:
    from station.batch import format_table

    progress = TerminalProgress()
    with Session(config, method, out, request=request, observer=progress,
                 nominal=nominal) as s:
        if s.resumed:
            print(f"resuming the session in {out} ({len(s.measured)} poses recorded)",
                  flush=True)
        files = s.run()
        print()
        print(format_table(s.outcome))
        for v in s.validation or ():
            before = "n/a" if v["rms_before"] is None else f"{v['rms_before']:.4g}"
            print(f"validation {v['channel']}: RMS {before} -> {v['rms_after']:.4g} {v['unit']} "
                  f"over {v['n']} held-out poses")
        print(f"trace {files['trace']}\nparameter file {files['params']} ({files['checksum']})\n"
              f"report {files['report']}")
    return 0
