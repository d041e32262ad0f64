"""``app.py devices check --config FILE | --simulate [--robot R]``: connect and print live
readings (:func:`drivers.check.main`; a real station: docs/real-station.md)."""
from __future__ import annotations

from cli.common import add_chain_arguments, delegate


def add_parser(sub) -> None:
    d = sub.add_parser("devices", help="devices")
    dsub = d.add_subparsers(dest="devices_command", required=True)
    dc = dsub.add_parser("check", help="connect and print live readings")
    dc.add_argument("--config")
    dc.add_argument("--endpoints", help="simulator endpoints file to fill the config from")
    dc.add_argument("--seconds", type=float, default=3.0)
    dc.add_argument("--simulate", action="store_true",
                    help="start the simulated station (--robot) and check it")
    dc.add_argument("--robot", default="agebot-sm", metavar="ROBOT",
                    help="with --simulate: agebot-sm (default), agebot-pm, a robot file (TOML) "
                         "or a URDF (with --base-link, --tip-link)")
    add_chain_arguments(dc)
    dc.add_argument("--truth", help="with --simulate: the simulated robot's truth file (a "
                                    "robot file's or URDF robot's)")
    dc.set_defaults(func=delegate("drivers.check", "main"), robot_chain=True)
