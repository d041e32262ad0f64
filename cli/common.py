"""What several commands share: the parser whose mistakes are one line, a URDF robot's
chain arguments, the checks of output files and of the numbers every command takes, the
hand-over to the station module that runs a command, and :func:`run`, main's error
handling (every refusal one line on stderr, exit 2)."""
from __future__ import annotations

import argparse
import os
import sys

#: the most poses a command plans (far more than a station measures; bounds time and memory)
MAX_COUNT = 100_000


class Parser(argparse.ArgumentParser):
    """argparse whose mistakes are one line, ``error: ...`` and exit 2, like every
    other refusal of the command line (the usage is a ``--help`` away)."""

    def error(self, message):
        text = " ".join(f"{self.prog}: {message}".split())
        self.exit(2, f"error: {text} (see {self.prog} --help)\n")


def add_chain_arguments(p) -> None:
    """``--base-link``/``--tip-link``: a URDF robot's chain (``--robot FILE.urdf``)."""
    p.add_argument("--base-link", help="URDF robot: the link the chain starts at")
    p.add_argument("--tip-link", help="URDF robot: the link the chain ends at")


def delegate(module: str, func: str):
    """The command's function: ``module.func(args)``, imported when the command runs."""
    def run(args) -> int:
        from importlib import import_module

        try:
            mod = import_module(module)
        except ModuleNotFoundError as e:
            if e.name and e.name.startswith(module.split(".")[0]):
                raise SystemExit(f"this command is not available in this build ({module})")
            raise
        return getattr(mod, func)(args)
    return run


def check_outputs(*outputs, inputs=()) -> None:
    """Refuse, before any work, output files (``(path, what)``, path None = not
    asked for) that cannot be written, would overwrite an input or each other, or
    are not regular files (:func:`drivers.atomic.check_outputs`: one check for
    every command)."""
    from drivers.atomic import check_outputs as check

    check(*outputs, inputs=inputs)


def file_inputs(*paths) -> tuple:
    """The paths among ``paths`` that name files (a built-in robot's name is none)."""
    return tuple(p for p in paths if p and (os.path.exists(p) or os.sep in p
                                            or p.lower().endswith((".toml", ".urdf", ".json",
                                                                   ".jsonl", ".csv"))))


def check_args(args) -> None:
    """The numbers every command takes, checked at the edge before any work: a
    one-line ConfigError naming the option (never numpy's or Dask's traceback later)."""
    import math

    from calibration.errors import ConfigError

    def integer(name, lo, hi, what):
        v = getattr(args, name, None)
        if v is not None and not lo <= v <= hi:
            flag = "--" + name.replace("_", "-")
            raise ConfigError(f"{flag} {v}: expected {what}")

    integer("seed", 0, 2 ** 63 - 1, "a seed of 0 or more")
    integer("sim_seed", 0, 2 ** 63 - 1, "a seed of 0 or more")
    integer("count", 1, MAX_COUNT, f"a number of poses from 1 to {MAX_COUNT} (leave it out "
                                    "for the default)")
    integer("max_iter", 1, 10 ** 6, "a number of iterations from 1 to 1000000")
    integer("workers", 1, 1024, "a number of worker processes from 1 to 1024 (leave it out "
                                "for one per core)")
    integer("robots", 1, MAX_COUNT, f"a number of robots from 1 to {MAX_COUNT}")
    seconds = getattr(args, "seconds", None)
    if seconds is not None and not (math.isfinite(seconds) and 0 < seconds <= 86400):
        raise ConfigError(f"--seconds {seconds}: expected a time in seconds, more than 0 "
                          "and at most 86400")
    method = getattr(args, "method", None)
    if method is not None and args.command in ("run", "study", "trace", "batch"):
        from calibration.methods import METHODS

        if method not in METHODS:
            raise ConfigError(f"--method {method!r}: unknown method (known: "
                              f"{', '.join(METHODS)})")
    sched = getattr(args, "scheduler", None)
    if sched is not None:
        import re

        if not re.fullmatch(r"(tcp|tls|inproc|ucx)://[^\s/:]+:\d{1,5}/?", sched):
            raise ConfigError(f"--scheduler {sched!r}: expected a Dask scheduler's address, "
                              "tcp://HOST:PORT")


def one_line(e) -> str:
    return " ".join(str(e).split())


def run(args) -> int:
    """Check ``args``, resolve a URDF robot's chain and run the command: its exit code, or
    2 with one ``error: ...`` line on stderr for a refusal (:class:`StationError`, a file
    the command cannot write, a ``SystemExit`` with a reason), 130 when interrupted."""
    from calibration.errors import StationError

    try:
        check_args(args)
        if getattr(args, "robot_chain", False) and args.robot:   # a URDF with its chain
            from drivers.robot_file import robot_ref

            args.robot = robot_ref(args.robot, args.base_link, args.tip_link)
        return int(args.func(args) or 0)
    except StationError as e:
        print(f"error: {one_line(e)}", file=sys.stderr)
        return 2
    except OSError as e:   # a file the command writes: disk full, permissions, ...
        where = f"{e.filename}: " if e.filename else ""
        print(f"error: {where}{e.strerror or one_line(e)}", file=sys.stderr)
        return 2
    except KeyboardInterrupt as e:
        print(str(e) or "interrupted", file=sys.stderr)
        return 130
    except SystemExit as e:
        if isinstance(e.code, str):
            print(f"error: {e.code}", file=sys.stderr)
            return 2
        raise
