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
from station.trace import utc_now

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
                    extra: dict | None = None) -> dict:
    """The parameter file's content (without checksum) for a solver result; ``poses``
    is the number of fit poses (the model's ``n_poses``; a pose gives one row per
    measured channel, ``fit.rows``)."""
    params = {}
    for j, (name, st) in enumerate(zip(result.names, result.status)):
        params[name] = {
            "value": float(result.x[j]),
            "nominal": float(nominal[j]),
            "std": _f(result.std[j]) if st.identifiable else None,
            "identifiable": bool(st.identifiable),
            "influences_model": bool(st.influences_model) if not st.identifiable else False,
        }
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


def read_params(path) -> dict:
    """Read and verify a parameter file: format, version, fields and checksum."""
    path = str(path)
    try:
        doc = json.loads(Path(path).read_text(encoding="utf-8"))
    except OSError as e:
        raise TraceFormatError(f"cannot read the parameter file: {e.strerror}", file=path) from None
    except (UnicodeDecodeError, json.JSONDecodeError) as e:
        raise TraceFormatError(f"not valid JSON ({e})", file=path) from None
    if not isinstance(doc, dict):
        raise TraceFormatError("a parameter file must be a JSON object", file=path)
    if doc.get("format") != FORMAT:
        raise TraceFormatError(f"format must be {FORMAT!r}, not {doc.get('format')!r}", file=path)
    if doc.get("version") != VERSION:
        raise TraceFormatError(f"unsupported parameter file version {doc.get('version')!r} "
                               f"(this reader knows version {VERSION})", file=path)
    for key in ("robot", "method", "created", "parameters", "fit", "covariance", "checksum"):
        if key not in doc:
            raise TraceFormatError(f"missing field {key!r}", file=path)
    if doc["checksum"] != checksum(doc):
        raise TraceFormatError("checksum does not match: the file was damaged or edited", file=path)
    for name, p in doc["parameters"].items():
        for key in ("value", "nominal", "std", "identifiable", "influences_model"):
            if key not in p:
                raise TraceFormatError(f"parameters.{name}: missing field {key!r}", file=path)
    return doc
