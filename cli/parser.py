"""The command line put together: :func:`build_parser` adds each command's sub-parser in
the order ``--help`` lists them, :func:`main` parses, sets up logging and warnings, and
runs the command (:func:`cli.common.run`: every refusal one line, exit 2)."""
from __future__ import annotations

import argparse
import logging
import sys
import warnings

from cli import (accuracy, batch, compensate, devices, doctor, gui, params, run, simulate,
                 study, trace, truth)
from cli.common import Parser, one_line
from cli.common import run as run_command

#: the commands in the order of ``app.py --help``
COMMANDS = (batch, params, trace, simulate, devices, run, study, truth, compensate, accuracy,
            gui, doctor)


def build_parser() -> argparse.ArgumentParser:
    p = Parser(prog="app.py", description="Robot calibration station")
    p.add_argument("-v", "--verbose", action="store_true", help="log details to stderr")
    sub = p.add_subparsers(dest="command")
    for command in COMMANDS:
        command.add_parser(sub)
    return p


def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING,
                        format="%(levelname)s %(name)s: %(message)s")
    if not args.verbose:     # the driver names a failed link itself, in one line
        logging.getLogger("pymodbus").setLevel(logging.CRITICAL)
    if args.command is None:
        args = parser.parse_args(["gui", *(argv or [])])
    # a warning for people is one line, without the source line that raised it
    warnings.showwarning = lambda message, category, filename, lineno, file=None, line=None: \
        print(f"warning: {one_line(message)}", file=file or sys.stderr)
    return run_command(args)
