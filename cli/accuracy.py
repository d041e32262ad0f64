"""``app.py accuracy --simulate --robot R --truth T --params PARAMS.json --out ACC.csv``:
ISO 9283 pose accuracy and repeatability before and after the calibration;
``--params PARAMS.json --csv ACC.csv`` the test's page again (:func:`station.accuracy.main`,
docs/accuracy.md)."""
from __future__ import annotations

from cli.common import add_chain_arguments, delegate


def add_parser(sub) -> None:
    ac = sub.add_parser("accuracy", help="pose accuracy and repeatability as ISO 9283 defines "
                        "them, before and after the calibration (docs/accuracy.md)")
    ac.add_argument("--simulate", action="store_true")
    ac.add_argument("--robot", metavar="ROBOT",
                    help="the URDF (with --base-link, --tip-link)")
    add_chain_arguments(ac)
    ac.add_argument("--truth", help="with --simulate: the simulated robot's truth file")
    ac.add_argument("--config", help="the station config (with --simulate: the simulated "
                    "station's; default the URDF robot's own)")
    ac.add_argument("--endpoints", help="without --simulate: fill --config's \"@endpoints\" "
                    "from a running simulator's endpoints file")
    ac.add_argument("--params", required=True, help="the parameter file (sm-markers)")
    ac.add_argument("--out", metavar="ACCURACY.csv",
                    help="every measured cycle (written atomically)")
    ac.add_argument("--report", metavar="FILE.html",
                    help="the test's HTML page (default: the CSV's name with .html); linked "
                         "from the session's report.html beside --params")
    ac.add_argument("--csv", metavar="ACCURACY.csv",
                    help="write the page again from a measured CSV and --params (nothing "
                         "moves; no --robot, --out)")
    ac.add_argument("--cycles", type=int, default=30,
                    help="cycles of each program (the standard's 30; fewer with a note)")
    ac.add_argument("--cube", metavar="X,Y,Z,SIZE",
                    help="the test cube's centre and edge, mm in the base link frame "
                         "(default: the largest that fits where the instrument sees the tool)")
    ac.add_argument("--seed", type=int, default=0, help="seed of the cube's search")
    ac.add_argument("--sim-seed", type=int, help="seed of the simulated noise (default: the "
                    "truth file's)")
    ac.set_defaults(func=delegate("station.accuracy", "main"), robot_chain=True)
