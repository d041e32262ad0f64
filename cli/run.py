"""``app.py run [--simulate] --robot R --method M --out DIR``: a whole station session,
headless (:func:`station.headless.main`; a real station: docs/real-station.md)."""
from __future__ import annotations

from cli.common import add_chain_arguments, delegate


def add_parser(sub) -> None:
    r = sub.add_parser("run", help="a whole station session, headless")
    r.add_argument("--simulate", action="store_true")
    r.add_argument("--robot", required=True, metavar="ROBOT",
                   help="agebot-sm, agebot-pm, a robot file (TOML) or a URDF (with "
                        "--base-link, --tip-link)")
    add_chain_arguments(r)
    r.add_argument("--method", required=True)
    r.add_argument("--truth")
    r.add_argument("--config")
    r.add_argument("--out", required=True, help="folder for trace.jsonl, params.json, "
                   "report.html (an existing trace there is resumed)")
    r.add_argument("--count", type=int, help="poses to fit (default: twice eq. 60's minimum)")
    r.add_argument("--seed", type=int, default=0, help="seed of the pose planner")
    r.add_argument("--design", choices=("optimal", "random"), default="optimal",
                   help="optimal (default): each round's poses the D-optimal choice of a pool "
                        "of candidates given those measured; random: drawn in the box "
                        "(docs/design.md)")
    r.add_argument("--target-std", metavar="[NAME=]STD",
                   help="add poses until the predicted std meets this: STD alone is the "
                        "tool's held-out error (m; rad for a wrist), NAME=STD a parameter's")
    r.add_argument("--one-shot", action="store_true",
                   help="sm-distance, sm-distance-tilt: plan every pose at once with the start "
                        "values, without the scout rounds and the live watch of the default "
                        "(safe only where the start values are close: docs/cli.md)")
    r.add_argument("--sim-seed", type=int, help="seed of the simulated noise and faults "
                   "(default: the truth file's; printed and recorded in the trace)")
    r.add_argument("--endpoints", help="without --simulate: fill --config's \"@endpoints\" "
                   "from a running simulator's endpoints file")
    r.add_argument("--nominal", action="append", metavar="NAME=VALUE",
                   help="a start value the engineer knows (repeatable), e.g. k3=1.111e-4; "
                        "sm-plane also plane_a/plane_b/plane_c")
    r.add_argument("--accept-poor-fit", action="store_true",
                   help="export the calibration even if the fit fails the quality gate "
                        "(recorded in the parameter file's fit.quality)")
    r.set_defaults(func=delegate("station.headless", "main"), robot_chain=True)
