"""``app.py truth draw --robot R --seed N --out TRUTH.json``: a simulated robot drawn
around a nominal, for ``run --simulate``, ``simulate`` and the wizard's ``--truth``
(:func:`station.simulation.truth_cli.draw_truth_file`, which the wizard's "Draw one"
writes too)."""
from __future__ import annotations

import argparse
import math

from cli.common import add_chain_arguments


def add_parser(sub) -> None:
    """``truth draw`` on the app's sub-command parser ``sub``."""
    from drivers.sim.truth import DRAW_SPREAD

    t = sub.add_parser("truth", help="simulator truth files")
    tsub = t.add_subparsers(dest="truth_command", required=True)
    d = tsub.add_parser("draw", help="draw a simulated robot around a robot file's (or "
                                     "AGEBOT's) nominal, for --truth")
    d.add_argument("--robot", required=True, metavar="ROBOT",
                   help="a robot file (TOML), a URDF (with --base-link, --tip-link), "
                        "agebot-sm or agebot-pm")
    add_chain_arguments(d)
    d.add_argument("--seed", type=int, default=0, help="seed of the draw and of the "
                   "simulator's noise (default 0)")
    d.add_argument("--out", required=True, help="the truth file to write (JSON)")
    d.add_argument("--gear", type=float, help="gear ratios within +-GEAR (relative; default "
                   f"{DRAW_SPREAD['gear']:g}, as the study command)")
    d.add_argument("--length", type=float, help="lengths within +-LENGTH (relative; default "
                   f"{DRAW_SPREAD['length']:g})")
    d.add_argument("--offset", type=float, help="offsets and angles within +-OFFSET (rad; "
                   f"default {DRAW_SPREAD['offset']:g})")
    d.add_argument("--repeatability", metavar="BACKLASH,POSITIONING",
                   help="the drives' backlash and random positioning error per move (rad, "
                        "every joint, e.g. 2e-5,1e-5: a few arc-seconds; default none: the "
                        "simulated robot positions exactly; docs/accuracy.md)")
    d.set_defaults(func=draw, robot_chain=True)


def draw(args: argparse.Namespace) -> int:
    from drivers.atomic import check_writable
    from drivers.robot_file import split_urdf_ref
    from drivers.sim.truth import DRAW_SPREAD
    from station.simulation.truth_cli import draw_truth_file

    check_writable(args.out, "the truth file", inputs=(args.robot,))
    path = draw_truth_file(args.robot, args.out, args.seed, gear=args.gear,
                           length=args.length, offset=args.offset,
                           repeatability=getattr(args, "repeatability", None))
    spread = {k: DRAW_SPREAD[k] if getattr(args, k) is None else getattr(args, k)
              for k in ("gear", "length", "offset")}
    if split_urdf_ref(args.robot) is not None:
        from drivers.sim.truth import load_truth

        t = load_truth(path)
        print(f"truth written to {path} and its true URDF to {path.parent / t.robot_file}: "
              f"{args.robot} drawn around its nominal (seed {args.seed}; joint origins by mm "
              f"and mrad, joint zeros by mrad), a motion-capture room and {len(t.points)} markers "
              f"on the tool; use it with --truth {path}")
        return 0
    print(f"truth written to {path}: {args.robot} drawn around its nominal (seed {args.seed}; "
          f"gear ratios +-{spread['gear']:.3g}, lengths +-{spread['length']:.3g} relative, "
          f"offsets +-{math.degrees(spread['offset']):.3g}\u00b0); use it with --truth "
          f"{path}")
    return 0
