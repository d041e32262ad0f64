#!/usr/bin/env python3
"""The calibration station's one entry point (docs/cli.md).

    python app.py                      the operator's Qt wizard
    python app.py batch TRACE --out PARAMS.json
    python app.py params verify PARAMS.json
    python app.py trace generate --method M --out TRACE [--truth FILE] [--noise ...]
    python app.py simulate --robot R [--truth FILE] [--endpoints FILE]
    python app.py devices check --config FILE | --simulate [--robot R]
    python app.py run --simulate --robot R --method M [--truth FILE] --out DIR
    python app.py run --config FILE --robot R --method M --out DIR   (docs/real-station.md)
    python app.py study --method M --robots N --out DIR
    python app.py truth draw --robot R --seed N --out TRUTH.json
    python app.py compensate PARAMS.json --program IN.csv --out OUT.csv
    python app.py accuracy --simulate --robot R --truth T --params PARAMS.json --out ACC.csv
    python app.py accuracy --params PARAMS.json --csv ACC.csv   the test's page again
    python app.py doctor               what this machine lacks, and how to install it

Every command exits 0 on success and non-zero with a one-line reason on stderr
otherwise; no command leaves a partial output file behind.

Each command's options and the function that runs it: cli/ (one module a command).
"""
import sys

from cli import build_parser, main

__all__ = ["build_parser", "main"]

if __name__ == "__main__":
    sys.exit(main())
