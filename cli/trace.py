"""``app.py trace generate --method M --out TRACE``: a simulated trace from a truth file
plus noise (the built-in robots' :mod:`station.simulation.tracegen`, a robot file's
:mod:`~station.simulation.tracegen_serial`, a URDF's :mod:`~station.simulation.tracegen_urdf`);
``app.py trace import CSV --robot FILE --method M --out TRACE``: a trace from a CSV of
joint values and measurements (:mod:`station.recording.trace_import`)."""
from __future__ import annotations

from cli.common import add_chain_arguments, check_outputs, file_inputs


def add_parser(sub) -> None:
    from calibration.methods import METHODS

    t = sub.add_parser("trace", help="traces")
    tsub = t.add_subparsers(dest="trace_command", required=True)
    g = tsub.add_parser("generate", help="simulate a trace from a truth file plus noise")
    g.add_argument("--method", required=True, choices=tuple(METHODS), metavar="METHOD",
                   help="one of: " + ", ".join(METHODS))
    g.add_argument("--robot", help="a robot file (TOML) or a URDF (with --base-link, "
                                   "--tip-link; sm-markers); default: the method's built-in robot")
    add_chain_arguments(g)
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
    g.set_defaults(func=generate)
    im = tsub.add_parser("import", help="a trace from a CSV of joint values and measurements "
                                        "(robot files: docs/robot-files.md; URDF robots and "
                                        "points on the tool: docs/urdf-robots.md)")
    im.add_argument("csv")
    im.add_argument("--robot", required=True, help="the robot file (TOML) or URDF")
    add_chain_arguments(im)
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
    im.set_defaults(func=import_trace)


def import_trace(args) -> int:
    from station.recording.trace_import import import_command

    check_outputs((args.out, "the trace"),
                  inputs=(args.csv, args.robot, args.validation, args.joint_map))
    print(import_command(args))
    return 0


def generate(args) -> int:
    from calibration.errors import ConfigError
    from calibration.methods import METHODS
    from calibration.robots import BUILTIN
    from drivers.urdf_file import is_urdf

    check_outputs((args.out, "the trace"), inputs=file_inputs(args.robot, args.truth))
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
