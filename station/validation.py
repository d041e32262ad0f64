"""Held-out validation: how well a calibration predicts poses it was not fitted to.

Per measured channel, RMS and max |error| of the trace's held-out poses
(``use = "validation"``) before calibration and after, in the channel's unit.
"""
from __future__ import annotations

import numpy as np

from calibration.errors import CalibrationError
from calibration.methods import build, extra_params
from station.batch import BatchOutcome


def validation_errors(outcome: BatchOutcome) -> list[dict]:
    """Per channel: RMS and max |error| of the held-out poses before calibration (the
    nominal; for sm-distance-tilt the nominal in the captured base frame) and after
    (empty if the trace holds no held-out poses)."""
    trace = outcome.trace
    if not trace.validation_poses:
        return []
    robot = trace.robot_model()
    if robot.name == "agebot-pm":    # the start values there are already a fit
        x_before = trace.nominal_vector(robot, extra_params(trace.method, robot))
    else:
        x_before = np.asarray(outcome.model.x0, dtype=float)
    data = trace.method_data(use="validation")
    opts = {}
    if trace.method in ("pm-fk", "pm-ik", "pm-tilt"):
        opts["start"] = "nominal"
    if trace.method == "sm-plane":
        opts["plane_given"] = True
    model = build(trace.method, robot, data, outcome.result.x, **opts)
    out = []
    after = _in_metres(trace.method, model.evaluate(outcome.result.x)[0], outcome.result.x, robot)
    try:
        before = _in_metres(trace.method, model.evaluate(x_before)[0], x_before, robot)
        before_note = ""
    except CalibrationError as e:
        before, before_note = None, str(e)
    for k, ch in enumerate(model.channels):
        rows = model.row_channel == k
        a = after[rows]
        rec = {"channel": ch, "unit": _unit(trace.method, ch), "n": int(rows.sum()),
               "rms_after": float(np.sqrt(np.mean(a ** 2))), "max_after": float(np.abs(a).max())}
        if before is not None:
            b = before[rows]
            rec.update(rms_before=float(np.sqrt(np.mean(b ** 2))),
                       max_before=float(np.abs(b).max()))
        else:
            rec.update(rms_before=None, max_before=None, note=before_note)
        out.append(rec)
    return out


def _in_metres(method: str, residual, x, robot):
    """sm-plane: the residual ``a x + b y + c z + 1`` of a contact as its distance (m)
    from the plane of ``x``; others unchanged."""
    if method != "sm-plane":
        return residual
    return residual / np.linalg.norm(np.asarray(x, dtype=float)[robot.n_params:])


def _unit(method: str, channel: str) -> str:
    if channel in ("distance", "x", "y", "z", "dx", "dy", "plane"):
        return "m"
    if method == "pm-ik":
        return "actuator units"
    return "rad"
