"""``app.py batch TRACE --out PARAMS.json``: calibrate a recorded trace headless
(:func:`station.fitting.batch.calibrate_trace`, the one path of the session and the
wizard too), print the fit's table and write the parameter file (and the report)."""
from __future__ import annotations

import sys
import warnings

from cli.common import check_outputs

OUTLIER_MODES = ("exclude", "flag", "off")   # station.fitting.verdict.OUTLIER_MODES


def add_parser(sub) -> None:
    b = sub.add_parser("batch", help="calibrate a recorded trace headless")
    b.add_argument("trace")
    b.add_argument("--out", required=True, help="parameter file to write")
    b.add_argument("--method", help="override the trace's method")
    b.add_argument("--report", help="also write an HTML report")
    b.add_argument("--residual", choices=("plain", "squared"),
                   help="distance residual D_M - D (plain, default) or D_M^2 - D^2 (report)")
    b.add_argument("--max-iter", type=int, default=1000)
    b.add_argument("--accept-poor-fit", action="store_true",
                   help="write the parameter file even if the fit fails the quality gate "
                        "(recorded in its fit.quality)")
    b.add_argument("--outliers", choices=OUTLIER_MODES, default="exclude",
                   help="readings that do not fit the others: exclude them and refit "
                        "(default), flag them (named, kept in the fit) or off (not judged); "
                        "recorded in the parameter file")
    b.add_argument("--exclude", metavar="POSE,...",
                   help="leave these poses (trace indices) out of the fit and the held-out "
                        "set, with --exclude-reason (recorded in the parameter file)")
    b.add_argument("--exclude-reason", metavar="TEXT", help="why --exclude's poses are left out")
    b.add_argument("--distance-scale", metavar="S[,STD]",
                   help="the draw-wire's scale factor and its std (a calibration certificate, "
                        "a known reference length): distance and tilt do not observe it; "
                        "every calibrated length carries it")
    b.add_argument("--compliance", action="store_true",
                   help="URDF robots: also fit each joint's compliance under gravity (the "
                        "URDF's inertials) and keep it only where the data support it "
                        "(docs/compliance.md)")
    b.add_argument("--payload", metavar="MASS[,X,Y,Z]",
                   help="with --compliance: the payload on the tip link (kg; its centre in "
                        "the tip link's frame, m)")
    b.add_argument("--hold", metavar="NAME,...",
                   help="hold these parameters at their start values besides the robot's "
                        "fixed ones (shell patterns, e.g. 'j*' for a URDF robot's joint "
                        "origins: a joint-offset calibration)")
    b.set_defaults(func=run)


def run(args) -> int:
    from calibration.solver import SolverOptions
    from station.fitting.batch import calibrate_trace
    from station.outputs.fit_summary import format_table
    from station.outputs.report import write_outputs

    check_outputs((args.out, "the parameter file"), (args.report, "the report"),
                  inputs=(args.trace,))
    opts = SolverOptions(max_iter=args.max_iter)
    if args.hold:
        from station.fitting.batch import hold_patterns

        opts = SolverOptions(max_iter=args.max_iter,
                             fixed=hold_patterns(args.trace, args.hold, args.method))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        outcome = calibrate_trace(args.trace, method=args.method, residual=args.residual,
                                  options=opts, accept_poor_fit=args.accept_poor_fit,
                                  exclude=exclusions(args.exclude, args.exclude_reason),
                                  outliers=args.outliers,
                                  compliance=compliance(args.compliance, args.payload),
                                  distance_scale=distance_scale(args.distance_scale))
    for w in caught:
        print(f"warning: {w.message}", file=sys.stderr)
    print(format_table(outcome))
    outcome = write_outputs(outcome, args.trace, args.out, args.report)
    if args.report:
        print(f"report written to {args.report}")
    print(f"parameter file written to {args.out} ({outcome.document['checksum']})")
    return 0


def distance_scale(text: str | None):
    """``--distance-scale S[,STD]`` as ``(s, std, source)`` (or None)."""
    import math

    from calibration.errors import ConfigError

    if not text:
        return None
    try:
        vals = [float(v) for v in text.split(",")]
    except ValueError:
        vals = []
    if len(vals) not in (1, 2) or not all(math.isfinite(v) for v in vals) \
            or not 0.5 < vals[0] < 2 or (len(vals) == 2 and not 0 <= vals[1] < 0.1):
        raise ConfigError(f"--distance-scale {text[:40]}: give S[,STD], the draw-wire's scale "
                          "factor (0.5 to 2, e.g. 1.0012 from its certificate) and its std")
    return vals[0], (vals[1] if len(vals) == 2 else 0.0), "--distance-scale"


def compliance(offered: bool, payload: str | None) -> dict | None:
    """``--compliance [--payload MASS[,X,Y,Z]]`` as ``{"payload": {...}}`` (or None)."""
    from calibration.errors import ConfigError

    if payload and not offered:
        raise ConfigError("--payload goes with --compliance")
    if not offered:
        return None
    if not payload:
        return {}
    try:
        vals = [float(v) for v in payload.split(",")]
    except ValueError:
        raise ConfigError(f"--payload {payload[:40]}: give MASS[,X,Y,Z] (kg, m in the tip "
                          "link's frame)") from None
    if len(vals) not in (1, 4) or not all(v == v and abs(v) < 1e4 for v in vals) \
            or vals[0] < 0:
        raise ConfigError(f"--payload {payload[:40]}: give MASS[,X,Y,Z] (kg >= 0, m in the "
                          "tip link's frame)")
    return {"payload": {"mass": vals[0], "com": vals[1:] or [0.0, 0.0, 0.0]}}


def exclusions(text: str | None, reason: str | None) -> dict | None:
    """``--exclude 5,12`` with ``--exclude-reason TEXT`` as ``{5: TEXT, 12: TEXT}``."""
    from calibration.errors import ConfigError

    if not text:
        if reason:
            raise ConfigError("--exclude-reason goes with --exclude POSE,...")
        return None
    if not reason or not reason.strip():
        raise ConfigError("--exclude needs --exclude-reason \"why\" (recorded in the parameter "
                          "file)")
    out = {}
    for item in text.split(","):
        item = item.strip()
        if not item.isdigit():
            raise ConfigError(f"--exclude: {item[:20]!r} is not a pose index (the trace's "
                              f"pose indices, e.g. --exclude 5,12)")
        out[int(item)] = " ".join(reason.split())
    return out
