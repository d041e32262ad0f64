"""Held-out validation: how well a calibration predicts poses it was not fitted to.

Per measured channel, RMS and max |error| of the trace's held-out poses
(``use = "validation"``) before calibration and after, in the channel's unit;
and each held-out reading against its own prediction std (noise plus the fitted
parameters' uncertainty, :func:`calibration.quality.worst_prediction`): the most
significant one beyond the Bonferroni threshold is named as ``outlier`` in its
channel's record (the gate refuses the fit then).
"""
from __future__ import annotations

import numpy as np

from calibration import quality as q
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
    raw, W = model.evaluate(outcome.result.x)
    after = _in_metres(trace.method, raw, outcome.result.x, robot)
    worst = heldout_outlier(outcome, model, raw, W)
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
        if worst is not None and worst[0].channel == ch:
            o, n_test = worst
            rp = _row_pose(model)
            pose = None if rp is None else int(trace.validation_poses[int(rp[o.row])]["index"])
            rec["outlier"] = {"pose": pose, "residual": float(after[o.row]),
                              "std": float(abs(after[o.row]) / o.t), "t": o.t,
                              "threshold": o.threshold, "rows_tested": n_test}
        out.append(rec)
    return out


def heldout_outlier(outcome: BatchOutcome, model, raw, W) -> tuple | None:
    """The held-out row (of ``model``, the validation poses' model; ``raw, W`` its
    residual and Jacobian at the solution) whose prediction error is most
    significant against its prediction std, if beyond the Bonferroni threshold
    over the held-out rows: ``(Outlier, rows tested)`` with the row of ``model``;
    else None. The noise and the parameters' covariance are the fit's."""
    fit, result = outcome.model, outcome.result
    channels = tuple(fit.channels)
    if any(ch not in channels for ch in model.channels):
        return None
    rc = np.array([channels.index(model.channels[k]) for k in model.row_channel], dtype=int)
    # the validation model's columns in the fit's order (a parameter it does not
    # free, sm-plane's given plane, adds no uncertainty to the prediction)
    W_new = np.zeros((len(raw), len(result.names)))
    for j, name in enumerate(model.names):
        if name in result.names:
            W_new[:, result.names.index(name)] = W[:, j]
    std, dof = q.prediction_std(fit, result, W_new, rc)
    o, n_test = q.worst_prediction(raw, std, dof, rc, channels)
    return None if o is None else (o, n_test)


def _row_pose(model) -> np.ndarray | None:
    from station.gate import row_poses

    return row_poses(model)


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
