"""Calibration traces: JSON Lines, ``format = "calstation-trace"``, ``version = 1``
(docs/file-formats.md).

A parsed trace (:class:`Trace`) and its reader: :func:`read_trace` skips a truncated last
line with a warning and refuses anything else that is malformed, naming the line. The
writer (one line each, flushed and fsynced) is :mod:`station.recording.trace_writer`.
"""
from __future__ import annotations

import datetime as _dt
import json
import os
import sys
import warnings
from dataclasses import dataclass, field

import numpy as np

from calibration.errors import CalibrationError, TraceFormatError
from calibration.methods import METHODS, MethodData, extra_params
from calibration.methods.sm_distance import ZEROS   # the reference's ``zero`` (added field)
from calibration.methods.sm_markers import points_array
from calibration.robots import get_robot
from drivers.robot_file import spec_from_source
from station.recording.trace_checks import (  # noqa: F401 (FORMAT, VERSION, COMPONENTS: here too)
    COMPONENTS, FORMAT, VERSION, check_header, check_method_needs, check_pose_channels,
    check_remeasure, check_vector)

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
    #: pose index -> the index of the pose record that measured that pose again
    #: (its ``remeasure_of``): a reading measured again stays in ``poses`` (the report
    #: shows it) and is neither fitted nor held out: a pose's newest reading is the one used
    remeasured: dict = field(default_factory=dict)

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
    def current_poses(self) -> list[dict]:
        """Every pose's newest reading (:attr:`remeasured` ones left out)."""
        return [p for p in self.poses if p["index"] not in self.remeasured]

    @property
    def fit_poses(self) -> list[dict]:
        """The poses to calibrate with (``use`` absent or ``"fit"``; newest readings)."""
        return [p for p in self.current_poses if p.get("use", "fit") == "fit"]

    @property
    def validation_poses(self) -> list[dict]:
        """Held-out poses (``use = "validation"``; newest readings): checked, never fitted."""
        return [p for p in self.current_poses if p.get("use") == "validation"]

    def readings_of(self, index: int) -> list[dict]:
        """Every reading of the pose whose newest reading is pose ``index``, the first
        first (one where it was not measured again)."""
        earlier = {new: old for old, new in self.remeasured.items()}
        by_index = {p["index"]: p for p in self.poses}
        out = [by_index[index]]
        while out[0]["index"] in earlier:
            out.insert(0, by_index[earlier[out[0]["index"]]])
        return out

    def method_data(self, method: str | None = None, use: str = "fit") -> MethodData:
        """Arrays for :func:`calibration.methods.build` of the ``use`` poses
        (``"fit"``, ``"validation"`` or ``"all"``)."""
        method = method or self.method
        poses = {"fit": self.fit_poses, "validation": self.validation_poses,
                 "all": self.current_poses}[use]
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

def read_trace(path: str | os.PathLike, *, method_override: str | None = None) -> Trace:
    """Parse and validate a trace file (see module doc)."""
    path = str(path)
    try:
        f = open(path, "rb")
    except OSError as e:
        raise TraceFormatError(f"cannot read the trace: {e.strerror}", file=path) from None
    with f:
        return _read_lines(path, _lines(path, f), method_override)


def _lines(path: str, f):
    """``(lineno, line, ended)``: the file's lines without their ``\\n`` and whether each
    had one (only the last may not), read one at a time (a 100 000-pose trace is never
    held whole beside its records). An empty file is one empty line, as
    ``b"".split(b"\\n")`` has it."""
    lineno = 0
    while True:
        try:
            bline = f.readline()
        except OSError as e:
            raise TraceFormatError(f"cannot read the trace: {e.strerror}", file=path) from None
        if not bline:
            break
        lineno += 1
        ended = bline.endswith(b"\n")
        yield lineno, (bline[:-1] if ended else bline), ended
    if lineno == 0:
        yield 1, b"", False


def _read_lines(path: str, lines, method_override) -> Trace:
    """:func:`read_trace` of the file's ``lines`` (:func:`_lines`)."""
    trace: Trace | None = None
    n_act = 0
    last_index = -1
    intern = sys.intern
    for lineno, bline, ended in lines:
        def fail(msg, _ln=lineno):
            raise TraceFormatError(msg, file=path, line=_ln)

        if not bline.strip():
            fail("empty line")
        try:
            rec = json.loads(bline.decode("utf-8"))
        except RecursionError:
            fail("the JSON is nested too deeply")
        except (UnicodeDecodeError, json.JSONDecodeError) as e:
            if not ended:
                warnings.warn(f"{path}:{lineno}: skipped a truncated last line "
                              f"(the recording was interrupted)", TruncatedLineWarning, stacklevel=3)
                if trace is not None:
                    trace.truncated_tail = True
                break
            if isinstance(e, UnicodeDecodeError):
                fail("not a text file (not UTF-8): is it a trace?")
            fail(f"not valid JSON ({e.msg.lower()} at column {e.colno}): is it a trace "
                 "(one JSON record a line)?")
        if not isinstance(rec, dict):
            fail("a record must be a JSON object")
        # every record's keys (and kind) one string each, not one per record: a
        # 100 000-pose trace's records are a fifth smaller
        rec = {intern(k): v for k, v in rec.items()}
        kind = rec.get("record")
        if isinstance(kind, str):
            kind = rec["record"] = intern(kind)
        if kind not in RECORDS:
            fail(f"unknown record kind {kind!r} (known: {', '.join(RECORDS)})")
        if lineno == 1:
            if kind != "header":
                fail("the first line must be the header record")
            head = check_header(rec, fail, method_override)
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
        check_vector(rec["qm"], n_act, "qm", fail)
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
        check_pose_channels(rec, trace, fail)
        if "group" in rec and (not isinstance(rec["group"], int) or isinstance(rec["group"], bool)):
            fail(f"group must be an integer, not {rec['group']!r}")
        if rec.get("use", "fit") not in ("fit", "validation"):
            fail(f"use must be 'fit' or 'validation', not {rec['use']!r}")
        if "remeasure_of" in rec:
            check_remeasure(rec, trace, fail)
        trace.poses.append(rec)
    if trace is None:
        raise TraceFormatError("the trace is empty (no header)", file=path, line=1)
    check_method_needs(trace)
    return trace


def pose_name(o: dict) -> str:
    """``pose 51``, or for a pose imported from a CSV ``pose 51 (held.csv:16)``: the file
    and line a user finds it at (``o``: an entry with ``pose`` and, where known, ``where``,
    the pose record's ``source``)."""
    return f"pose {o['pose']}" + (f" ({o['where']})" if o.get("where") else "")
