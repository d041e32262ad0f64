"""Parameter files: JSON, ``format = "calstation-params"``, ``version = 1``
(docs/file-formats.md), written atomically with a SHA-256 checksum over the
canonical JSON of every other field.
"""
from __future__ import annotations

import hashlib
import json
import math
import os
from pathlib import Path

import numpy as np

from calibration.errors import TraceFormatError
from drivers.atomic import write_atomic
from station.recording.trace import utc_now

FORMAT = "calstation-params"
VERSION = 1


def canonical(obj) -> bytes:
    return json.dumps(obj, sort_keys=True, separators=(",", ":"), allow_nan=False).encode("utf-8")


def checksum(doc: dict) -> str:
    body = {k: v for k, v in doc.items() if k != "checksum"}
    return "sha256:" + hashlib.sha256(canonical(body)).hexdigest()


def file_sha256(path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 16), b""):
            h.update(chunk)
    return h.hexdigest()


def _f(v):
    v = float(v)
    return v if math.isfinite(v) else None


def params_document(result, *, robot: str, nominal: np.ndarray, trace_path: str | None,
                    poses: int, frame: dict | None = None, notes: list[str] | None = None,
                    extra: dict | None = None, quality: dict | None = None) -> dict:
    """The parameter file's content (without checksum) for a solver result; ``poses``
    is the number of fit poses (the model's ``n_poses``; a pose gives one row per
    measured channel, ``fit.rows``); ``quality`` the fit-quality gate's result
    (``fit.quality``)."""
    params = {}
    for j, (name, st) in enumerate(zip(result.names, result.status)):
        params[name] = {
            "value": float(result.x[j]),
            "nominal": float(nominal[j]),
            "std": _f(result.std[j]) if st.identifiable else None,
            "identifiable": bool(st.identifiable),
            "influences_model": bool(st.influences_model) if not st.identifiable else False,
        }
        if getattr(st, "fixed", False):
            params[name]["fixed"] = True
    doc = {
        "format": FORMAT,
        "version": VERSION,
        "robot": robot,
        "method": result.method,
        "created": utc_now(),
        "source_trace": ({"file": os.path.basename(trace_path), "sha256": file_sha256(trace_path)}
                         if trace_path else None),
        "parameters": params,
        "fit": {
            "converged": bool(result.converged),
            "iterations": int(result.iterations),
            "sigma": {k: _f(v) for k, v in result.sigma.items()},
            "sigma_known": bool(result.sigma_known),
            "residual_rms": {k: _f(v) for k, v in result.residual_rms.items()},
            "condition_number": _f(result.condition_number),
            "identifiable_count": int(result.n_identifiable),
            "poses": int(poses),
            "rows": int(result.n_rows),
            "message": result.message,
        },
        "covariance": {"names": list(result.covariance_names),
                       "matrix": [[float(v) for v in row] for row in np.atleast_2d(result.covariance)]},
    }
    if quality is not None:
        doc["fit"]["quality"] = quality
    if frame is not None:
        doc["frame"] = frame
    if notes:
        doc["notes"] = list(notes)
    if extra:
        doc.update(extra)
    return doc


def write_params(path, doc: dict) -> dict:
    """Add the checksum and write the file atomically; returns the document."""
    doc = dict(doc)
    doc["checksum"] = checksum(doc)
    write_atomic(path, (json.dumps(doc, indent=2, sort_keys=True, allow_nan=False) + "\n").encode())
    return doc


_NUM = {"type": "number"}
_NUM_OR_NULL = {"type": ["number", "null"]}
# The parameter file's structure (file-formats.md); values are checked by _check_values.
SCHEMA = {
    "type": "object",
    "required": ["format", "version", "robot", "method", "created", "parameters", "fit",
                 "covariance", "checksum"],
    "properties": {
        "format": {"const": FORMAT},
        "version": {"type": "integer", "const": VERSION},
        "robot": {"type": "string"},
        "method": {"type": "string"},
        "created": {"type": "string"},
        "checksum": {"type": "string", "pattern": "^sha256:[0-9a-f]{64}$"},
        "source_trace": {"oneOf": [{"type": "null"}, {
            "type": "object", "required": ["file", "sha256"],
            "properties": {"file": {"type": "string"}, "sha256": {"type": "string"}}}]},
        "parameters": {"type": "object", "minProperties": 1, "additionalProperties": {
            "type": "object",
            "required": ["value", "nominal", "std", "identifiable", "influences_model"],
            "properties": {"value": _NUM, "nominal": _NUM,
                           "std": {"oneOf": [{"type": "null"}, {"type": "number", "minimum": 0}]},
                           "identifiable": {"type": "boolean"},
                           "influences_model": {"type": "boolean"},
                           "fixed": {"type": "boolean"},
                           "absorbs": {"type": "array", "items": {"type": "string"}}}}},
        "fit": {"type": "object",
                "properties": {"converged": {"type": "boolean"},
                               "iterations": {"type": "integer", "minimum": 0},
                               "sigma": {"type": "object", "additionalProperties": _NUM_OR_NULL},
                               "residual_rms": {"type": "object",
                                                "additionalProperties": _NUM_OR_NULL},
                               "condition_number": _NUM_OR_NULL,
                               "quality": {"type": "object",
                                           "required": ["passed", "accepted", "outliers", "checks"],
                                           "properties": {"passed": {"type": "boolean"},
                                                          "accepted": {"type": "boolean"},
                                                          "outliers": {"type": "array"},
                                                          "checks": {"type": "array"}}}}},
        "covariance": {"type": "object", "required": ["names", "matrix"],
                       "properties": {"names": {"type": "array", "items": {"type": "string"}},
                                      "matrix": {"type": "array", "items": {
                                          "type": "array", "items": _NUM}}}},
        "frame": {"type": "object"},
        "robot_file": {"type": "object"},
        "notes": {"type": "array", "items": {"type": "string"}},
        "not_identified": {"type": "array", "items": {
            "type": "object", "required": ["direction", "statement", "std_rad"],
            "properties": {"direction": {"type": "string"}, "statement": {"type": "string"},
                           "std_rad": {"type": "number", "minimum": 0}}}},
    },
}


def _reject_constant(name):
    raise ValueError(f"{name} is not a JSON number")


def _finite_float(text: str) -> float:
    v = float(text)
    if not math.isfinite(v):
        raise ValueError(f"the number {text[:30]} is out of range (beyond 1.8e308)")
    return v


def _sane_int(text: str) -> int:
    if len(text.lstrip("-")) > 300:
        raise ValueError(f"the number {text[:30]}... is out of range ({len(text)} digits)")
    return int(text)


def _no_duplicates(pairs) -> dict:
    out = {}
    for k, v in pairs:
        if k in out:
            raise ValueError(f"the key {_short(k)} appears twice in one object (which one "
                             "holds?)")
        out[k] = v
    return out


def read_params(path) -> dict:
    """Read and verify a parameter file: structure against :data:`SCHEMA`, values
    (robot, method, parameter names, covariance shape), and checksum."""
    import jsonschema

    path = str(path)
    try:
        doc = json.loads(Path(path).read_text(encoding="utf-8"), parse_constant=_reject_constant,
                         parse_float=_finite_float, parse_int=_sane_int,
                         object_pairs_hook=_no_duplicates)
    except OSError as e:
        raise TraceFormatError(f"cannot read the parameter file: {e.strerror}", file=path) from None
    except RecursionError:
        raise TraceFormatError("the JSON is nested too deeply", file=path) from None
    except (UnicodeDecodeError, ValueError) as e:  # JSONDecodeError is a ValueError
        raise TraceFormatError(f"not valid JSON ({e})", file=path) from None
    if not isinstance(doc, dict):
        raise TraceFormatError("a parameter file must be a JSON object", file=path)
    if doc.get("format") != FORMAT:
        raise TraceFormatError(f"format must be {FORMAT!r}, not {_short(doc.get('format'))}",
                               file=path)
    if doc.get("version") != VERSION or isinstance(doc.get("version"), bool):
        raise TraceFormatError(f"unsupported parameter file version {_short(doc.get('version'))} "
                               f"(this reader knows version {VERSION})", file=path)
    try:
        err = jsonschema.exceptions.best_match(
            jsonschema.Draft202012Validator(SCHEMA).iter_errors(doc))
    except RecursionError:
        raise TraceFormatError("the JSON is nested too deeply", file=path) from None
    if err is not None:
        where = ".".join(str(k) for k in err.absolute_path) or "the file"
        raise TraceFormatError(f"{where}: {_short(err.message, 120)}", file=path)
    _check_values(doc, path)
    if doc["checksum"] != checksum(doc):
        raise TraceFormatError("checksum does not match: the file was damaged or edited", file=path)
    return doc


def _short(v, n: int = 60) -> str:
    text = v if isinstance(v, str) and n > 60 else repr(v)
    return text if len(text) <= n else text[:n - 3] + "..."


def _check_values(doc: dict, path: str) -> None:
    """What a schema cannot say: a known robot and method, the method's parameters,
    a square covariance over calibrated parameters."""
    from calibration.errors import ConfigError
    from calibration.methods import METHODS, extra_params
    from calibration.methods.sm_distance import DISTANCE_OFF
    from calibration.robots import ROBOTS, get_robot
    from drivers.robot_file import spec_from_source

    def fail(msg):
        raise TraceFormatError(msg, file=path)

    robot, method = doc["robot"], doc["method"]
    if "robot_file" in doc:
        try:
            model = get_robot(spec_from_source(doc["robot_file"], "robot_file"))
        except ConfigError as e:
            fail(" ".join(str(e).split()))
        if model.name != robot:
            fail(f"robot: {_short(robot)} is not the robot file's name {model.name!r}")
    elif robot not in ROBOTS:
        fail(f"robot: unknown robot {_short(robot)} (known: {', '.join(ROBOTS)}, or a file "
             f"with robot_file)")
    else:
        model = get_robot(robot)
    if method not in METHODS or METHODS[method].kind != model.kind:
        fail(f"method: {_short(method)} is not a method of {robot}")
    from calibration.methods.sm_markers import marker_count

    names = set(model.param_names) | set(extra_params(method, model,
                                                      marker_count(doc["parameters"])))
    if "distance" in METHODS[method].channels:
        names.add(DISTANCE_OFF)       # a draw-wire zero that was a reading
    extra = set(doc["parameters"]) - names
    if extra:
        fail(f"parameters: unknown {sorted(extra)} for {robot} {method}")
    cov = doc["covariance"]
    n = len(cov["names"])
    if set(cov["names"]) - set(doc["parameters"]):
        fail(f"covariance.names: not parameters: "
             f"{sorted(set(cov['names']) - set(doc['parameters']))}")
    if len(cov["matrix"]) != n or any(len(row) != n for row in cov["matrix"]):
        fail(f"covariance.matrix must be {n} x {n} (one row and column per name)")


# Calibrated gear ratios and lengths must stay within this factor of their start
# values (a sign flip or a halving is a mis-wired reading, not a robot): the gate's
# rule (station/fitting/gate.py), which a parameter file is checked against again
PLAUSIBLE_FACTOR = 2.0
#: the most a calibrated value may move from its start value, in units of the larger
#: of 1 and the start value's size (angles in rad, lengths in m: 1000 is no robot)
MAX_MOVE = 1e3


def factor_judged(name: str, x0: float, robot, *, serial: bool, method: str | None = None) -> bool:
    """Whether the calibrated ``name`` of ``robot`` (start value ``x0``) must keep its
    sign and stay within :data:`PLAUSIBLE_FACTOR` of ``x0``: AGEBOT's gear ratios and
    lengths (not its zeros ``*_off``, angles ``theta*``, a method's plane, nor
    sm-distance-tilt's frame ``a0``); a robot file's (``serial``) gear ratios ``k*``
    and its lengths ``d*``, ``a*`` not near 0; a URDF robot's gear ratios only (its
    joint origins, zeros and the instrument frame are judged by their shift and turn,
    :func:`station.fitting.gate_checks.check_plausible_serial`). The gate and the
    parameter file's check (:func:`check_usable`) ask this one rule."""
    if x0 == 0 or name not in robot.param_names:
        return False
    if not serial:
        frame = ("a0",) if method == "sm-distance-tilt" else ()
        return not (name.endswith("_off") or name.startswith(("theta", "plane_"))
                    or name in frame)
    if name.startswith("k"):
        return True
    urdf = hasattr(robot, "calibrated_origins")
    return not urdf and name[0] in "da" and name[1:].isdigit() and abs(x0) > 1e-3


def check_usable(doc: dict, path: str) -> None:
    """What ``params verify`` and the exports ask of a parameter file beyond its
    structure and checksum (a checksum recomputed over an edit proves nothing): a fit
    that converged and passed the quality gate, or one whose poor fit was accepted
    on purpose (``fit.quality.accepted``); a parameter the fit did not calibrate at
    its start value; none moved by more than :data:`MAX_MOVE` times its size; every
    calibrated gear ratio and length of the robot with its start value's sign and
    within the gate's factor of it (:func:`factor_judged`, the gate's rule). A :class:`TraceFormatError` naming the file and the
    parameter otherwise."""
    from calibration.robots import get_robot
    from drivers.robot_file import spec_from_source

    def fail(msg):
        raise TraceFormatError(msg, file=path)

    fit = doc.get("fit") or {}
    quality = fit.get("quality")
    accepted = bool(quality and quality.get("accepted"))
    if quality is not None and not quality.get("passed") and not accepted:
        failed = [c.get("check") for c in quality.get("checks", ())
                  if isinstance(c, dict) and c.get("ok") is False and c.get("check")]
        fail("fit.quality: the fit failed the quality gate"
             + (f" ({', '.join(str(f) for f in failed[:3])})" if failed else "")
             + " and was not accepted (batch --accept-poor-fit records that on purpose)")
    if fit.get("converged") is False and not accepted:
        fail("fit.converged: the fit did not converge")
    for name, p in doc["parameters"].items():
        x0, x = float(p["nominal"]), float(p["value"])
        if not p.get("identifiable") and abs(x - x0) > 1e-9 * max(1.0, abs(x0)):
            fail(f"parameters.{name}: {x:.6g}, but the fit did not calibrate it (not "
                 f"identifiable): it keeps its start value {x0:.6g}")
        if not accepted and abs(x - x0) > MAX_MOVE * max(1.0, abs(x0)):
            fail(f"parameters.{name}: {x:.6g} against its start value {x0:.6g}: moved by "
                 f"more than {MAX_MOVE:g} times its size, not a plausible calibration")
    if accepted:        # a poor fit kept on purpose: its values are what they are
        return
    serial = "robot_file" in doc
    model = (get_robot(spec_from_source(doc["robot_file"], "robot_file"))
             if serial else get_robot(doc["robot"]))
    for name, p in doc["parameters"].items():
        x0, x = float(p["nominal"]), float(p["value"])
        if not p.get("identifiable") or not factor_judged(name, x0, model, serial=serial,
                                                          method=doc.get("method")):
            continue
        ratio = x / x0
        if not 1 / PLAUSIBLE_FACTOR <= ratio <= PLAUSIBLE_FACTOR:
            fail(f"parameters.{name}: {x:.6g} against its start value {x0:.6g} ({ratio:.3g} "
                 f"times): not a plausible calibration (gear ratios and lengths keep their "
                 f"sign and stay within a factor {PLAUSIBLE_FACTOR:g})")
