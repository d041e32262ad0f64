"""``app.py doctor``: what this machine lacks (Python packages, the wizard's system
libraries with the ``apt-get`` command, display; :func:`station.doctor.main`)."""
from __future__ import annotations

from cli.common import delegate


def add_parser(sub) -> None:
    doc = sub.add_parser("doctor", help="check this machine: Python packages, the wizard's "
                                        "system libraries (with the apt-get command), display")
    doc.set_defaults(func=delegate("station.doctor", "main"))
