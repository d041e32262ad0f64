"""``app.py simulate --robot R``: the simulated devices as a standalone process until
stopped (:func:`drivers.sim.server.main`)."""
from __future__ import annotations

import argparse

from cli.common import add_chain_arguments, delegate


def add_parser(sub) -> None:
    s = sub.add_parser("simulate", help="run the simulated devices until stopped")
    s.add_argument("--robot", required=True, metavar="ROBOT",
                   help="agebot-sm, agebot-pm, a robot file (TOML) or a URDF (with "
                        "--base-link, --tip-link)")
    add_chain_arguments(s)
    s.add_argument("--truth")
    s.add_argument("--config")
    s.add_argument("--endpoints", help="write the devices' endpoints (JSON) here")
    s.add_argument("--seed", type=int, help="seed of the simulated noise and faults "
                   "(default: the truth file's)")
    s.add_argument("--pose-noise", action="store_true",
                   help="the noise of a reading at rest is a function of the seed and the pose "
                        "(a pose read twice reads the same; for comparing runs)")
    s.add_argument("--exit-with-parent", action="store_true", help=argparse.SUPPRESS)
    s.set_defaults(func=delegate("drivers.sim.server", "main"), robot_chain=True)
