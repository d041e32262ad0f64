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
"""
from __future__ import annotations

import argparse
import logging
import os
import sys
import warnings



OUTLIER_MODES = ("exclude", "flag", "off")   # station.fitting.verdict.OUTLIER_MODES

def _cmd_batch(args) -> int:
    from calibration.solver import SolverOptions
    from station.fitting.batch import calibrate_trace
    from station.outputs.fit_summary import format_table
    from station.outputs.report import write_outputs

    _check_outputs((args.out, "the parameter file"), (args.report, "the report"),
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
                                  exclude=_exclusions(args.exclude, args.exclude_reason),
                                  outliers=args.outliers,
                                  compliance=_compliance(args.compliance, args.payload),
                                  distance_scale=_distance_scale(args.distance_scale))
    for w in caught:
        print(f"warning: {w.message}", file=sys.stderr)
    print(format_table(outcome))
    outcome = write_outputs(outcome, args.trace, args.out, args.report)
    if args.report:
        print(f"report written to {args.report}")
    print(f"parameter file written to {args.out} ({outcome.document['checksum']})")
    return 0


def _distance_scale(text: str | None):
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


def _compliance(offered: bool, payload: str | None) -> dict | None:
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


def _exclusions(text: str | None, reason: str | None) -> dict | None:
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


def _check_outputs(*outputs, inputs=()) -> None:
    """Refuse, before any work, output files (``(path, what)``, path None = not
    asked for) that cannot be written, would overwrite an input or each other, or
    are not regular files (:func:`drivers.atomic.check_outputs`: one check for
    every command)."""
    from drivers.atomic import check_outputs

    check_outputs(*outputs, inputs=inputs)


def _cmd_params_verify(args) -> int:
    from station.outputs.params_file import check_usable, read_params

    doc = read_params(args.file)
    check_usable(doc, args.file)
    n_id = sum(p["identifiable"] for p in doc["parameters"].values())
    accepted = (doc["fit"].get("quality") or {}).get("accepted")
    print(f"{args.file}: OK ({doc['format']} v{doc['version']}, robot {doc['robot']}, method "
          f"{doc['method']}, {n_id} of {len(doc['parameters'])} parameters calibrated, "
          f"{doc['checksum']})" + ("; a poor fit accepted on purpose (--accept-poor-fit): "
                                   "fit.quality says what failed" if accepted else ""))
    return 0


def _cmd_params_export(args) -> int:
    from station.outputs.export import export_command

    for line in export_command(args):
        print(line, file=sys.stderr if line.startswith("warning:") else sys.stdout)
    return 0


def _cmd_trace_import(args) -> int:
    from station.recording.trace_import import import_command

    _check_outputs((args.out, "the trace"),
                   inputs=(args.csv, args.robot, args.validation, args.joint_map))
    print(import_command(args))
    return 0


def _file_inputs(*paths) -> tuple:
    """The paths among ``paths`` that name files (a built-in robot's name is none)."""
    return tuple(p for p in paths if p and (os.path.exists(p) or os.sep in p
                                            or p.lower().endswith((".toml", ".urdf", ".json",
                                                                   ".jsonl", ".csv"))))


def _cmd_trace_generate(args) -> int:
    from calibration.errors import ConfigError
    from calibration.methods import METHODS
    from calibration.robots import BUILTIN
    from drivers.urdf_file import is_urdf

    _check_outputs((args.out, "the trace"), inputs=_file_inputs(args.robot, args.truth))
    if args.components is not None and args.method != "pm-fk":
        raise ConfigError(f"--components is for pm-fk (the measured orientation angles), "
                          f"not {args.method}")
    if args.robot and is_urdf(args.robot):
        from station.simulation.tracegen_urdf import generate_command

        print(generate_command(args))
        return 0
    if args.method == "sm-markers":
        raise ConfigError("sm-markers takes a URDF robot: --robot FILE.urdf --base-link B "
                          "--tip-link T")
    builtin = BUILTIN[METHODS[args.method].kind]
    if args.robot in ("agebot-sm", "agebot-pm") and args.robot != builtin:
        raise ConfigError(f"--robot {args.robot} with --method {args.method}: {args.method} is "
                          f"a method of {builtin} (the {args.robot}'s methods: "
                          + ", ".join(m for m, mi in METHODS.items()
                                      if BUILTIN.get(mi.kind) == args.robot) + ")")
    if args.robot and args.robot not in ("agebot-sm", "agebot-pm"):
        from station.simulation.tracegen_serial import generate_command

        print(generate_command(args))
        return 0
    from station.simulation.tracegen import generate_from_truth
    from station.outputs.units import MM_DEG, channel_si

    noise = generate_from_truth(
        args.out, args.method, truth=args.truth, noise=args.noise or (), seed=args.seed,
        count=args.count, known=tuple(k for k in (args.known or "").split(",") if k),
        components=(parse_components(args.components) if args.components is not None
                    else None),
        design=args.design)
    reads = METHODS[args.method].channels          # the noise of the trace's own channels
    shown = {k: v for k, v in noise.items() if k in reads
             and any(x for x in (v if isinstance(v, list) else [v]))}
    if not shown:
        how = "no --noise given" + (" and the truth file has none" if args.truth else "")
        print(f"trace written to {args.out}: noise-free readings ({how}; add e.g. "
              "--noise distance=1e-5 --noise tilt=1e-4, in m and rad)")
    else:
        text = ", ".join(
            f"{k} " + "/".join(MM_DEG.text(x, channel_si(k), ".3g")
                               for x in (v if isinstance(v, list) else [v]))
            for k, v in shown.items())
        print(f"trace written to {args.out} (reading noise std: {text}; seed {args.seed})")
    return 0


def parse_components(text: str) -> tuple[str, ...]:
    """``--components alpha,beta``: distinct names of alpha, beta, gamma."""
    from calibration.errors import ConfigError

    names = tuple(c.strip() for c in text.split(","))
    known = ("alpha", "beta", "gamma")
    if not names or any(c not in known for c in names) or len(set(names)) != len(names):
        raise ConfigError(f"--components {text!r}: expected distinct names of "
                          f"{', '.join(known)} separated by commas, e.g. alpha,beta")
    return names


def _delegate(module: str, func: str):
    def run(args) -> int:
        from importlib import import_module

        try:
            mod = import_module(module)
        except ModuleNotFoundError as e:
            if e.name and e.name.startswith(module.split(".")[0]):
                raise SystemExit(f"this command is not available in this build ({module})")
            raise
        return getattr(mod, func)(args)
    return run


class _Parser(argparse.ArgumentParser):
    """argparse whose mistakes are one line, ``error: ...`` and exit 2, like every
    other refusal of the command line (the usage is a ``--help`` away)."""

    def error(self, message):
        text = " ".join(f"{self.prog}: {message}".split())
        self.exit(2, f"error: {text} (see {self.prog} --help)\n")


def build_parser() -> argparse.ArgumentParser:
    from station.simulation.truth_cli import add_chain_arguments
    from station.simulation.truth_cli import add_parser as add_truth_parser

    from calibration.methods import METHODS

    p = _Parser(prog="app.py", description="Robot calibration station")
    p.add_argument("-v", "--verbose", action="store_true", help="log details to stderr")
    sub = p.add_subparsers(dest="command")

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
    b.set_defaults(func=_cmd_batch)

    pa = sub.add_parser("params", help="parameter files")
    psub = pa.add_subparsers(dest="params_command", required=True)
    v = psub.add_parser("verify", help="check format, version and checksum")
    v.add_argument("file")
    v.set_defaults(func=_cmd_params_verify)
    ex = psub.add_parser("export", help="a robot file's calibration as URDF and/or a "
                                        "calibrated robot file (docs/robot-files.md)")
    ex.add_argument("file")
    ex.add_argument("--urdf", help="URDF to write (refused where a ratio k is not 1)")
    ex.add_argument("--robot-file", help="calibrated robot file (TOML) to write")
    ex.set_defaults(func=_cmd_params_export)

    t = sub.add_parser("trace", help="traces")
    tsub = t.add_subparsers(dest="trace_command", required=True)
    g = tsub.add_parser("generate", help="simulate a trace from a truth file plus noise")
    g.add_argument("--method", required=True, choices=tuple(METHODS), metavar="METHOD",
                   help="one of: " + ", ".join(METHODS))
    g.add_argument("--robot", help="a robot file (TOML) or a URDF (with --base-link, "
                                   "--tip-link; sm-markers); default: the method's built-in robot")
    g.add_argument("--base-link", help="URDF robot: the link the chain starts at")
    g.add_argument("--tip-link", help="URDF robot: the link the chain ends at")
    g.add_argument("--out", required=True)
    g.add_argument("--truth", help="simulator truth file (default: the report's true values)")
    g.add_argument("--noise", action="append", metavar="CHANNEL=STD",
                   help="reading noise std in SI (m, rad), e.g. --noise distance=1e-4 --noise "
                        "tilt=1e-3 (repeatable); without it (and without a truth file's "
                        "noise) the readings are noise-free")
    g.add_argument("--seed", type=int, default=0)
    g.add_argument("--count", type=int, help="number of poses (default: eq. 60)")
    g.add_argument("--design", choices=("random", "optimal"), default="random",
                   help="random poses in the workspace box (default), or the D-optimal "
                        "COUNT of ten times as many candidates (docs/design.md)")
    g.add_argument("--components", help="pm-fk: measured components, e.g. alpha,beta")
    g.add_argument("--known", help="parameters whose true values go into the nominal, e.g. "
                                   "L4 (sm-self-redundancy) or L4,theta0,a0,plane_a,plane_b,plane_c")
    g.set_defaults(func=_cmd_trace_generate)
    im = tsub.add_parser("import", help="a trace from a CSV of joint values and measurements "
                                        "(robot files: docs/robot-files.md; URDF robots and "
                                        "points on the tool: docs/urdf-robots.md)")
    im.add_argument("csv")
    im.add_argument("--robot", required=True, help="the robot file (TOML) or URDF")
    im.add_argument("--base-link", help="URDF robot: the link the chain starts at")
    im.add_argument("--tip-link", help="URDF robot: the link the chain ends at")
    im.add_argument("--method", required=True)
    im.add_argument("--out", required=True)
    im.add_argument("--length-unit", choices=("m", "mm"), default="m",
                    help="unit of x, y, z, distance, points and prismatic joints in the CSV")
    im.add_argument("--angle-unit", choices=("rad", "deg"), default="rad",
                    help="unit of roll, pitch, yaw, tilt_roll, tilt_pitch and (URDF robots) "
                         "revolute joints in the CSV")
    im.add_argument("--sigma", action="append", metavar="CHANNEL=STD",
                    help="std of one reading in SI units (repeatable), e.g. position=1e-4, "
                         "marker=2e-4 (sm-markers: one point's x, y, z each)")
    im.add_argument("--validation", metavar="CSV",
                    help="sm-markers: rows of another file (same instrument frame) held out")
    im.add_argument("--ignore-columns", metavar="A,B,...",
                    help="sm-markers: columns to skip (timestamps, the instrument's figures)")
    im.add_argument("--joint-map", metavar="FILE",
                    help="sm-markers: how the URDF's joints follow from the controller's "
                         "columns (signs, zeros, couplings; docs/urdf-robots.md)")
    im.set_defaults(func=_cmd_trace_import)

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
    s.set_defaults(func=_delegate("drivers.sim.server", "main"), robot_chain=True)

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
    dc.set_defaults(func=_delegate("drivers.check", "main"), robot_chain=True)

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
    r.set_defaults(func=_delegate("station.headless", "main"), robot_chain=True)

    st = sub.add_parser("study", help="Monte Carlo calibrations over robots drawn around the "
                        "nominal, on Dask (docs/design.md)")
    st.add_argument("--method", required=True)
    st.add_argument("--robot", help="the method's robot (default: the one it is for)")
    add_chain_arguments(st)
    st.add_argument("--robots", type=int, required=True, help="robots to draw")
    st.add_argument("--design", default="optimal,random",
                    help="pose designs to compare, comma-separated (optimal, random)")
    st.add_argument("--count", type=int, help="poses per calibration (default: eq. 60)")
    st.add_argument("--seed", type=int, default=0)
    st.add_argument("--gear", type=float, default=0.4, help="gear ratios within +-GEAR (relative)")
    st.add_argument("--length", type=float, default=0.05, help="lengths within +-LENGTH (relative)")
    st.add_argument("--offset", type=float, default=0.03, help="offsets within +-OFFSET")
    st.add_argument("--noise", action="append", metavar="CHANNEL=STD",
                    help="reading noise (default: the station's devices averaged over 5 samples)")
    st.add_argument("--scheduler", help="an existing Dask scheduler, tcp://HOST:PORT (default: "
                    "a local cluster)")
    st.add_argument("--workers", type=int, help="local cluster: worker processes (default: cores)")
    st.add_argument("--out", required=True, help="folder for study.jsonl and summary.json")
    st.set_defaults(func=_delegate("station.simulation.study", "cli"), robot_chain=True)


    add_truth_parser(sub)       # truth draw: a simulated robot around a nominal

    cp = sub.add_parser("compensate", help="a program's joint values rewritten so that the "
                        "calibrated robot reaches the nominal targets (docs/compensation.md)")
    cp.add_argument("params", help="the parameter file")
    cp.add_argument("--program", required=True, metavar="IN.csv",
                    help="joint values as the nominal controller runs them, a row per target "
                         "(other columns are passed through)")
    cp.add_argument("--out", required=True, metavar="OUT.csv")
    cp.add_argument("--angle-unit", choices=("rad", "deg"),
                    help="URDF robots: unit of the revolute joints' columns (default rad)")
    cp.add_argument("--length-unit", choices=("m", "mm"),
                    help="URDF robots: unit of the prismatic joints' columns (default m)")
    cp.add_argument("--joint-map", metavar="FILE",
                    help="URDF robots: how the URDF's joints follow from the controller's "
                         "columns (docs/urdf-robots.md); written back into them")
    cp.set_defaults(func=_delegate("station.outputs.compensate", "main"))

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
    ac.set_defaults(func=_delegate("station.accuracy", "main"), robot_chain=True)

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

    doc = sub.add_parser("doctor", help="check this machine: Python packages, the wizard's "
                                        "system libraries (with the apt-get command), display")
    doc.set_defaults(func=_delegate("station.doctor", "main"))
    gui.set_defaults(func=_delegate("station.gui.app", "main"), robot_chain=True)
    return p


#: the most poses a command plans (far more than a station measures; bounds time and memory)
MAX_COUNT = 100_000


def _check_args(args) -> None:
    """The numbers every command takes, checked at the edge before any work: a
    one-line ConfigError naming the option (never numpy's or Dask's traceback later)."""
    import math

    from calibration.errors import ConfigError

    def integer(name, lo, hi, what):
        v = getattr(args, name, None)
        if v is not None and not lo <= v <= hi:
            flag = "--" + name.replace("_", "-")
            raise ConfigError(f"{flag} {v}: expected {what}")

    integer("seed", 0, 2 ** 63 - 1, "a seed of 0 or more")
    integer("sim_seed", 0, 2 ** 63 - 1, "a seed of 0 or more")
    integer("count", 1, MAX_COUNT, f"a number of poses from 1 to {MAX_COUNT} (leave it out "
                                    "for the default)")
    integer("max_iter", 1, 10 ** 6, "a number of iterations from 1 to 1000000")
    integer("workers", 1, 1024, "a number of worker processes from 1 to 1024 (leave it out "
                                "for one per core)")
    integer("robots", 1, MAX_COUNT, f"a number of robots from 1 to {MAX_COUNT}")
    seconds = getattr(args, "seconds", None)
    if seconds is not None and not (math.isfinite(seconds) and 0 < seconds <= 86400):
        raise ConfigError(f"--seconds {seconds}: expected a time in seconds, more than 0 "
                          "and at most 86400")
    method = getattr(args, "method", None)
    if method is not None and args.command in ("run", "study", "trace", "batch"):
        from calibration.methods import METHODS

        if method not in METHODS:
            raise ConfigError(f"--method {method!r}: unknown method (known: "
                              f"{', '.join(METHODS)})")
    sched = getattr(args, "scheduler", None)
    if sched is not None:
        import re

        if not re.fullmatch(r"(tcp|tls|inproc|ucx)://[^\s/:]+:\d{1,5}/?", sched):
            raise ConfigError(f"--scheduler {sched!r}: expected a Dask scheduler's address, "
                              "tcp://HOST:PORT")


def _one_line(e) -> str:
    return " ".join(str(e).split())


def main(argv=None) -> int:
    from calibration.errors import StationError

    parser = build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING,
                        format="%(levelname)s %(name)s: %(message)s")
    if not args.verbose:     # the driver names a failed link itself, in one line
        logging.getLogger("pymodbus").setLevel(logging.CRITICAL)
    if args.command is None:
        args = parser.parse_args(["gui", *(argv or [])])
    # a warning for people is one line, without the source line that raised it
    warnings.showwarning = lambda message, category, filename, lineno, file=None, line=None: \
        print(f"warning: {_one_line(message)}", file=file or sys.stderr)
    try:
        _check_args(args)
        if getattr(args, "robot_chain", False) and args.robot:   # a URDF with its chain
            from drivers.robot_file import robot_ref

            args.robot = robot_ref(args.robot, args.base_link, args.tip_link)
        return int(args.func(args) or 0)
    except StationError as e:
        print(f"error: {_one_line(e)}", file=sys.stderr)
        return 2
    except OSError as e:   # a file the command writes: disk full, permissions, ...
        where = f"{e.filename}: " if e.filename else ""
        print(f"error: {where}{e.strerror or _one_line(e)}", file=sys.stderr)
        return 2
    except KeyboardInterrupt as e:
        print(str(e) or "interrupted", file=sys.stderr)
        return 130
    except SystemExit as e:
        if isinstance(e.code, str):
            print(f"error: {e.code}", file=sys.stderr)
            return 2
        raise


if __name__ == "__main__":
    sys.exit(main())
