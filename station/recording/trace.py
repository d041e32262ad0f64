"""Calibration traces: JSON Lines, ``format = "calstation-trace"``, ``version = 1``
(docs/file-formats.md).

A parsed trace (:class:`Trace`) and its reader: :func:`read_trace` skips a truncated last
line with a warning and refuses anything else that is malformed, naming the line. The
writer (one line each, flushed and fsynced) is :mod:`station.recording.trace_writer`.
"""
from __future__ import annotations

import datetime as _dt
import json
import math
import os
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from calibration.errors import CalibrationError, ConfigError, TraceFormatError
from calibration.methods import METHODS, MethodData, extra_params
from calibration.methods.sm_distance import ZEROS   # the reference's ``zero`` (added field)
from calibration.methods.sm_markers import points_array
from calibration.robots import ROBOTS, get_robot
from drivers.robot_file import spec_from_source

FORMAT = "calstation-trace"
VERSION = 1
RECORDS = ("header", "reference", "pose", "event")
ROLES = ("base-origin", "reference-point")
# channel -> (shape per pose, methods); shape None = scalar
CHANNELS = {
    "pose": 4,  # [x, y, z, phi] (agebot-sm); [x, y, z, roll, pitch, yaw] (robot files)
    "position": 3,
    "distance": None,
    "tilt": None,  # phi (agebot-sm); [roll, pitch] for pm-tilt and robot files
    "orientation": 3,
}
COMPONENTS = ("alpha", "beta", "gamma")


class TruncatedLineWarning(UserWarning):
    pass


def utc_now() -> str:
    return _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="milliseconds").replace("+00:00", "Z")


@dataclass
class Trace:
    """A parsed trace. ``poses`` keep their records (dicts) as read."""

    path: str
    header: dict
    reference: dict | None = None
    poses: list[dict] = field(default_factory=list)
    events: list[dict] = field(default_factory=list)
    truncated_tail: bool = False

    _model: object = field(default=None, repr=False, compare=False)

    @property
    def robot(self) -> str:
        return self.header["robot"]

    def robot_model(self):
        """The robot model: the header's ``robot_file`` where it has one, else the
        built-in ``robot``."""
        if self._model is None:
            src = self.header.get("robot_file")
            self._model = get_robot(self.robot if src is None else
                                    spec_from_source(src, f"{self.path}:1: robot_file"))
        return self._model

    @property
    def method(self) -> str:
        return self.header["method"]

    def nominal_vector(self, robot=None, extra: tuple[str, ...] = (),
                       extra_default=None) -> np.ndarray:
        """Start values: the header's ``nominal`` over the robot model's nominal."""
        robot = robot or self.robot_model()
        nom = dict(self.header.get("nominal") or {})
        ext = {k: nom.pop(k) for k in list(nom) if k in extra}
        xi = robot.params(nom, source=f"{self.path}:1: nominal")
        tail = [float(ext.get(k, (extra_default or {}).get(k, 0.0))) for k in extra]
        return np.concatenate([xi, tail])

    @property
    def fit_poses(self) -> list[dict]:
        """The poses to calibrate with (``use`` absent or ``"fit"``)."""
        return [p for p in self.poses if p.get("use", "fit") == "fit"]

    @property
    def validation_poses(self) -> list[dict]:
        """Held-out poses (``use = "validation"``): checked, never fitted."""
        return [p for p in self.poses if p.get("use") == "validation"]

    def method_data(self, method: str | None = None, use: str = "fit") -> MethodData:
        """Arrays for :func:`calibration.methods.build` of the ``use`` poses
        (``"fit"``, ``"validation"`` or ``"all"``)."""
        method = method or self.method
        poses = {"fit": self.fit_poses, "validation": self.validation_poses,
                 "all": self.poses}[use]
        if not poses:
            raise CalibrationError(f"{self.path}: the trace has no {use} poses" if use != "fit"
                                   else f"{self.path}: the trace has no poses to fit")
        qm = np.array([p["qm"] for p in poses], dtype=float)
        mi = METHODS[method]
        channels = {}
        for ch in mi.channels:
            if ch == "markers":
                channels[ch] = points_array([p[ch] for p in poses], self.n_markers)
                continue
            channels[ch] = np.array([p[ch] for p in poses], dtype=float)
            if ch == "distance":       # a draw-wire's certified scale (distance_scale)
                channels[ch] = channels[ch] * self.distance_scale[0]
        group = None
        if any("group" in p for p in poses):
            group = np.array([p.get("group", -1) for p in poses])
        ref = None if self.reference is None else np.array(self.reference["qm"], dtype=float)
        comps = self.header.get("components")
        return MethodData(qm=qm, channels=channels, group=group, reference_qm=ref,
                          components=tuple(comps) if comps else None,
                          distance_zero=self.distance_zero)

    @property
    def distance_scale(self) -> tuple[float, float]:
        """The draw-wire's scale ``(s, std)`` the readings are multiplied by (header
        ``distance_scale``: a calibration certificate or a known reference length;
        default exact 1): distance and tilt do not observe it (docs/methods.md)."""
        d = self.header.get("distance_scale") or {}
        return float(d.get("value", 1.0)), float(d.get("std", 0.0))

    @property
    def n_markers(self) -> int:
        """Points on the tool of an sm-markers trace (header ``markers``), else 0."""
        return int(self.header.get("markers") or 0)

    def extra_params(self, method: str | None = None) -> tuple[str, ...]:
        """The method's parameters after the robot's (sm-markers: per point on the tool)."""
        return extra_params(method or self.method, self.robot_model(), self.n_markers)

    @property
    def distance_zero(self) -> str:
        """The draw-wire's zero at the reference: ``"exact"`` or ``"reading"``."""
        return "exact" if self.reference is None else self.reference.get("zero", "exact")


# -- reading ------------------------------------------------------------------------
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


def _check_vector(v, n, what, fail):
    if not isinstance(v, list) or len(v) != n:
        fail(f"{what} must be a list of {n} numbers")
    for x in v:
        if not _num(x):
            fail(f"{what} has a value that is not a finite number of sane magnitude: {_short(x)}")


def read_trace(path: str | os.PathLike, *, method_override: str | None = None) -> Trace:
    """Parse and validate a trace file (see module doc)."""
    path = str(path)
    try:
        raw = Path(path).read_bytes()
    except OSError as e:
        raise TraceFormatError(f"cannot read the trace: {e.strerror}", file=path) from None
    lines = raw.split(b"\n")
    ends_with_newline = raw.endswith(b"\n")
    if ends_with_newline:
        lines = lines[:-1]
    trace: Trace | None = None
    n_act = 0
    last_index = -1
    for lineno, bline in enumerate(lines, start=1):
        def fail(msg, _ln=lineno):
            raise TraceFormatError(msg, file=path, line=_ln)

        if not bline.strip():
            fail("empty line")
        try:
            rec = json.loads(bline.decode("utf-8"))
        except RecursionError:
            fail("the JSON is nested too deeply")
        except (UnicodeDecodeError, json.JSONDecodeError) as e:
            if lineno == len(lines) and not ends_with_newline:
                warnings.warn(f"{path}:{lineno}: skipped a truncated last line "
                              f"(the recording was interrupted)", TruncatedLineWarning, stacklevel=2)
                if trace is not None:
                    trace.truncated_tail = True
                break
            if isinstance(e, UnicodeDecodeError):
                fail("not a text file (not UTF-8): is it a trace?")
            fail(f"not valid JSON ({e.msg.lower()} at column {e.colno}): is it a trace "
                 "(one JSON record a line)?")
        if not isinstance(rec, dict):
            fail("a record must be a JSON object")
        kind = rec.get("record")
        if kind not in RECORDS:
            fail(f"unknown record kind {kind!r} (known: {', '.join(RECORDS)})")
        if lineno == 1:
            if kind != "header":
                fail("the first line must be the header record")
            head = _check_header(rec, fail, method_override)
            model = head.pop("_model")
            trace = Trace(path, head, _model=model)
            n_act = trace._model.n_actuators
            continue
        assert trace is not None
        if kind == "header":
            fail("a second header record")
        if kind == "event":
            trace.events.append(rec)
            continue
        if "qm" not in rec:
            fail(f"{kind} record has no 'qm'")
        _check_vector(rec["qm"], n_act, "qm", fail)
        if kind == "reference":
            # a later reference before the poses replaces the earlier (a recapture)
            if trace.poses:
                fail("the reference record must come before the poses")
            if rec.get("role") not in ROLES:
                fail(f"reference role must be one of {', '.join(ROLES)}, not {rec.get('role')!r}")
            if rec.get("zero", "exact") not in ZEROS:
                fail(f"reference zero must be one of {', '.join(ZEROS)}, not {rec.get('zero')!r}")
            trace.reference = rec
            continue
        # pose
        idx = rec.get("index")
        if not isinstance(idx, int) or isinstance(idx, bool) or idx <= last_index:
            fail(f"pose index must be an integer greater than {last_index}, not {idx!r}")
        last_index = idx
        _check_pose_channels(rec, trace, fail)
        if "group" in rec and (not isinstance(rec["group"], int) or isinstance(rec["group"], bool)):
            fail(f"group must be an integer, not {rec['group']!r}")
        if rec.get("use", "fit") not in ("fit", "validation"):
            fail(f"use must be 'fit' or 'validation', not {rec['use']!r}")
        trace.poses.append(rec)
    if trace is None:
        raise TraceFormatError("the trace is empty (no header)", file=path, line=1)
    _check_method_needs(trace)
    return trace


def _check_header(rec, fail, method_override):
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


def _check_pose_channels(rec, trace, fail):
    method = trace.method
    comps = trace.header.get("components") or list(COMPONENTS)
    builtin = "robot_file" not in trace.header
    for ch in METHODS[method].channels:
        if ch not in rec:
            fail(f"pose has no {ch!r} reading, which method {method} needs")
        v = rec[ch]
        if ch == "pose":
            _check_vector(v, 4 if builtin else 6, ch, fail)
        elif ch == "position":
            _check_vector(v, 3, ch, fail)
        elif ch == "orientation":
            _check_vector(v, len(comps) if method == "pm-fk" else 3, ch, fail)
        elif ch == "markers":
            n = trace.n_markers
            if not isinstance(v, list) or len(v) != n:
                fail(f"markers must be a list of {n} points ([x, y, z] or null)")
            for p in v:
                if p is not None:
                    _check_vector(p, 3, "a point of markers", fail)
            if all(p is None for p in v):
                fail("markers: no point seen in this pose")
            continue
        elif ch == "tilt" and (method == "pm-tilt" or not builtin):
            _check_vector(v, 2, "tilt ([roll, pitch])", fail)
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


def _short(v) -> str:
    """A value for a message, at most 60 characters."""
    text = repr(v)
    return text if len(text) <= 60 else text[:57] + "..."


def _check_method_needs(trace):
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
