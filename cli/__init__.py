"""The command line: ``python app.py COMMAND ...`` (docs/cli.md; app.py's docstring is the
usage summary).

One module per command, each with its sub-parser (``add_parser(sub)``) and the function
that runs it, or a hand-over to the station module that runs it (:func:`cli.common.delegate`);
:mod:`cli.common` holds what several commands share (the one-line parser, a URDF's chain
arguments, output checks, the numbers checked at the edge, main's error handling) and
:mod:`cli.parser` puts them together (:func:`build_parser`, :func:`main`). Imports
station/, drivers/ and calibration/; nothing there imports this package.
"""
from cli.parser import build_parser, main

__all__ = ["build_parser", "main"]
