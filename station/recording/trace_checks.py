"""The checks of a trace's records as :func:`station.recording.trace.read_trace` reads them:
the header (format, version, robot, method, nominal, sigma, components), a pose's channels
and their plausible ranges, a pose measured again, and what the method needs of the whole
trace. Each takes ``fail(message)``, which raises the reader's error naming the line."""
from __future__ import annotations

import math

from calibration.errors import ConfigError, TraceFormatError
from calibration.methods import METHODS, extra_params
from calibration.robots import ROBOTS, get_robot
from drivers.robot_file import spec_from_source

FORMAT = "calstation-trace"
VERSION = 1
COMPONENTS = ("alpha", "beta", "gamma")

# Largest magnitude a number of a trace may have (actuator values in encoder counts
# stay far below; 1e300 would overflow the model's arithmetic).
MAX_MAGNITUDE = 1e12
# Plausible readings: a distance in metres (a draw-wire is zeroed at the reference,
# so a reading below -1 cm is a wrong scale, sign or Modbus word order), angles in rad.
DISTANCE_RANGE = (-0.01, 100.0)
MAX_ANGLE = 4 * math.pi


def _num(v) -> bool:
    """A finite JSON number of sane magnitude (an integer like 10**400 is refused,
    not overflowed)."""
    if not isinstance(v, (int, float)) or isinstance(v, bool):
        return False
    try:
        return math.isfinite(v) and abs(v) <= MAX_MAGNITUDE
    except OverflowError:
        return False


def check_vector(v, n, what, fail):
    if not isinstance(v, list) or len(v) != n:
        fail(f"{what} must be a list of {n} numbers")
    for x in v:
        if not _num(x):
            fail(f"{what} has a value that is not a finite number of sane magnitude: {_short(x)}")


def check_header(rec, fail, method_override):
    if rec.get("format") != FORMAT:
        fail(f"format must be {FORMAT!r}, not {rec.get('format')!r}")
    if rec.get("version") != VERSION:
        fail(f"unsupported trace version {rec.get('version')!r} (this reader knows version {VERSION})")
    robot = rec.get("robot")
    if "robot_file" in rec:
        try:
            model = get_robot(spec_from_source(rec["robot_file"], "robot_file"))
        except ConfigError as e:
            fail(str(e))
        if model.name != robot:
            fail(f"robot {robot!r} is not the robot file's name {model.name!r}")
    elif robot not in ROBOTS:
        fail(f"unknown robot {robot!r} (known: {', '.join(ROBOTS)}, or a trace with robot_file)")
    else:
        model = get_robot(robot)
    method = method_override or rec.get("method")
    if not isinstance(method, str) or method not in METHODS:
        fail(f"unknown method {method!r} (known: {', '.join(METHODS)})")
    if METHODS[method].kind != model.kind:
        fail(f"method {method} needs a {METHODS[method].kind} robot; {robot} is a {model.kind} one")
    rec = dict(rec, method=method, _model=model)
    nominal = rec.get("nominal", {})
    if not isinstance(nominal, dict):
        fail("nominal must be an object: parameter name -> value")
    markers = rec.get("markers")
    if method == "sm-markers":
        if not isinstance(markers, int) or isinstance(markers, bool) or not 1 <= markers <= 1000:
            fail(f"markers must be the number of points on the tool (1 to 1000), not "
                 f"{_short(markers)}")
    elif markers is not None:
        fail(f"markers is for sm-markers traces, not {method}")
    known = set(model.param_names) | set(extra_params(method, model, markers or 0))
    for k, v in nominal.items():
        if k not in known:
            fail(f"nominal: unknown parameter {k!r} for {robot}/{method}")
        if not _num(v):
            fail(f"nominal: {k} must be a finite number, not {_short(v)}")
    sigma = rec.get("sigma")
    if sigma is not None:
        if not isinstance(sigma, dict):
            fail("sigma must be an object: channel -> standard deviation")
        for k, v in sigma.items():
            vals = v if isinstance(v, list) else [v]
            if not vals or not all(_num(x) and x > 0 for x in vals):
                fail(f"sigma: {k} must be a positive number (or list of them), not {_short(v)}")
    comps = rec.get("components")
    if comps is not None:
        if (not isinstance(comps, list) or not comps or any(c not in COMPONENTS for c in comps)
                or list(comps) != [c for c in COMPONENTS if c in comps]):
            fail(f"components must be a non-empty ordered subset of {list(COMPONENTS)}, not {comps!r}")
    return rec


def check_pose_channels(rec, trace, fail):
    method = trace.method
    comps = trace.header.get("components") or list(COMPONENTS)
    builtin = "robot_file" not in trace.header
    for ch in METHODS[method].channels:
        if ch not in rec:
            fail(f"pose has no {ch!r} reading, which method {method} needs")
        v = rec[ch]
        if ch == "pose":
            check_vector(v, 4 if builtin else 6, ch, fail)
        elif ch == "position":
            check_vector(v, 3, ch, fail)
        elif ch == "orientation":
            check_vector(v, len(comps) if method == "pm-fk" else 3, ch, fail)
        elif ch == "markers":
            n = trace.n_markers
            if not isinstance(v, list) or len(v) != n:
                fail(f"markers must be a list of {n} points ([x, y, z] or null)")
            for p in v:
                if p is not None:
                    check_vector(p, 3, "a point of markers", fail)
            if all(p is None for p in v):
                fail("markers: no point seen in this pose")
            continue
        elif ch == "tilt" and (method == "pm-tilt" or not builtin):
            check_vector(v, 2, "tilt ([roll, pitch])", fail)
        elif not _num(v):
            fail(f"{ch} must be a finite number, not {_short(v)}")
        if ch == "distance" and not DISTANCE_RANGE[0] <= v <= DISTANCE_RANGE[1]:
            fail(f"distance {v:.6g} m is not a distance the draw-wire can measure (expected "
                 f"{DISTANCE_RANGE[0]:g} to {DISTANCE_RANGE[1]:g} m): check the device's scale, "
                 f"sign and Modbus word order")
        if ch in ("tilt", "orientation"):
            vals = v if isinstance(v, list) else [v]
            if any(abs(x) > MAX_ANGLE for x in vals):
                fail(f"{ch} {_short(v)} is not an angle in radians (|value| > 4 pi): check the "
                     f"device's unit")


def check_remeasure(rec, trace, fail) -> None:
    """A pose record that measures an earlier one again (``remeasure_of``: that one's
    index, its newest reading, of the same use and plan pose): recorded in
    :attr:`Trace.remeasured`."""
    old = rec["remeasure_of"]
    by_index = {p["index"]: p for p in trace.poses}
    if not isinstance(old, int) or isinstance(old, bool) or old not in by_index:
        fail(f"remeasure_of must be the index of an earlier pose record, not {_short(old)}")
    if old in trace.remeasured:
        fail(f"pose {old} was measured again already, by pose {trace.remeasured[old]}")
    was = by_index[old]
    if was.get("use", "fit") != rec.get("use", "fit"):
        fail(f"pose {rec['index']} measures pose {old} again, so its use must be "
             f"{was.get('use', 'fit')!r}, not {rec.get('use', 'fit')!r}")
    if was.get("plan_index") != rec.get("plan_index"):
        fail(f"pose {rec['index']} measures pose {old} again, so its plan_index must be "
             f"{was.get('plan_index')!r}, not {rec.get('plan_index')!r}")
    trace.remeasured[old] = rec["index"]


def _short(v) -> str:
    """A value for a message, at most 60 characters."""
    text = repr(v)
    return text if len(text) <= 60 else text[:57] + "..."


def check_method_needs(trace):
    mi = METHODS[trace.method]
    if mi.reference and (trace.reference is None and trace.poses   # a session killed before
                         or trace.reference is not None           # its reference resumes
                         and trace.reference.get("role") != mi.reference):
        raise TraceFormatError(f"method {trace.method} needs a reference record with role "
                               f"{mi.reference!r} before the poses", file=trace.path)
    if trace.method == "sm-self-redundancy":
        for p in trace.poses:
            if "group" not in p:
                raise TraceFormatError(f"pose {p['index']} has no 'group' (sm-self-redundancy "
                                       f"pairs poses at the same x, y)", file=trace.path)
