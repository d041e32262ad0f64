"""``app.py`` / ``app.py gui [--simulate] [--config FILE] [--robot R]``: the operator's Qt
wizard (:func:`station.gui.app.main`); ``--check``: can it run here?"""
from __future__ import annotations

from cli.common import add_chain_arguments, delegate


def add_parser(sub) -> None:
    gui = sub.add_parser("gui", help="the operator's Qt wizard")
    gui.add_argument("--simulate", action="store_true")
    gui.add_argument("--config")
    gui.add_argument("--robot", help="preselect the robot: agebot-sm, agebot-pm, a robot "
                                     "file (TOML) or a URDF (with --base-link, --tip-link)")
    add_chain_arguments(gui)
    gui.add_argument("--truth", help="with --simulate and a robot file: the simulated arm's "
                                     "truth file")
    gui.add_argument("--check", action="store_true",
                     help="only check that the wizard can run here (system libraries, "
                          "display) and say what to install")
    gui.set_defaults(func=delegate("station.gui.app", "main"), robot_chain=True)
