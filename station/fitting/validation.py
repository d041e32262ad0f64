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
from calibration.methods import build
from station.fitting.outcome import BatchOutcome


def validation_errors(outcome: BatchOutcome) -> list[dict]:
    """Per channel: RMS and max |error| of the held-out poses before calibration (the
    nominal; for sm-distance-tilt the nominal in the captured base frame) and after
    (empty if the trace holds no held-out poses). Points on the tool (sm-markers) also
    get their 3D errors (``points``). Held-out poses outside the fitted poses' joint
    ranges are named (``outside_range``): their errors are extrapolation, reported but
    not judged as outliers."""
    trace = outcome.trace
    if not trace.validation_poses:
        return []
    robot = trace.robot_model()
    if robot.name == "agebot-pm":    # the start values there are already a fit
        x_before = trace.nominal_vector(robot, trace.extra_params())
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
    rp = _row_pose(model)
    outside = outside_fitted_range(trace, outcome.model, data.qm)
    inside_rows = None if rp is None else ~np.isin(rp, sorted(outside))
    idx = np.flatnonzero(np.ones(len(raw), bool) if inside_rows is None else inside_rows)
    W_fit = in_fit_columns(model, outcome.result, W, idx)
    del W                   # (a large held-out set: one Jacobian of it alive, not two)
    worst = heldout_outlier(outcome, model, raw, W_fit, idx)
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
        if hasattr(model, "point_errors") and k == 0:   # the points' 3D errors, once
            rec["points"] = point_record(model, trace.validation_poses, after,
                                         None if before is None else before)
        if outside and rp is not None:
            sel = rows & np.isin(rp, sorted(outside))
            if sel.any():
                rec["outside_range"] = outside_record(model, trace.validation_poses, outside,
                                                      after, sel)
        if worst is not None and worst[0].channel == ch:
            o, n_test = worst
            vp = None if rp is None else trace.validation_poses[int(rp[o.row])]
            pose = None if vp is None else int(vp["index"])
            groups = getattr(model, "row_group", None)
            res = float(after[o.row]) if groups is None else float(o.residual)
            rec["outlier"] = {"pose": pose, "residual": res, "std": float(abs(res) / o.t),
                              "t": o.t, "threshold": o.threshold, "rows_tested": n_test}
            if vp is not None and vp.get("source"):
                rec["outlier"]["where"] = vp["source"]
            if groups is not None:
                rec["outlier"]["point"] = int(model.marker_of[int(groups[o.row])]) + 1
        out.append(rec)
    return out


def outside_fitted_range(trace, fit_model, qm_heldout) -> dict:
    """Held-out poses (positions in the validation poses) with a joint value outside
    the range the fit poses cover: ``{position: "joint 4 2.1 beyond 1.9"}``."""
    qm_fit = np.asarray(getattr(fit_model, "qm", None) if fit_model is not None else None,
                        dtype=float)
    if qm_fit.ndim != 2 or qm_fit.shape[1] != np.shape(qm_heldout)[1]:
        return {}
    lo, hi = qm_fit.min(axis=0), qm_fit.max(axis=0)
    tol = 1e-9 * np.maximum(hi - lo, 1.0)
    robot = trace.robot_model()
    label = getattr(robot, "joint_label", lambda i: f"joint {i}")
    out = {}
    for i, pose in enumerate(np.asarray(qm_heldout, dtype=float)):
        bad = np.flatnonzero((pose < lo - tol) | (pose > hi + tol))
        if bad.size:
            j = int(bad[0])
            edge = lo[j] if pose[j] < lo[j] else hi[j]
            out[i] = (f"{label(j + 1)} {pose[j]:.4g} beyond the fitted "
                      f"{'minimum' if pose[j] < lo[j] else 'maximum'} {edge:.4g}")
    return out


def point_record(model, poses, after, before) -> dict:
    """3D errors of the held-out points (sm-markers): RMS and max, before and after, and
    the worst three named by pose and point."""
    e = model.point_errors(after)
    rec = {"n": int(e.size), "poses": len({int(p) for p in model.pose_of}),
           "rms_after": float(np.sqrt(np.mean(e ** 2))), "max_after": float(e.max())}
    if before is not None:
        b = model.point_errors(before)
        rec.update(rms_before=float(np.sqrt(np.mean(b ** 2))), max_before=float(b.max()))
    order = np.argsort(-e)[:3]
    rec["worst"] = [_with_source({"pose": int(poses[int(model.pose_of[g])]["index"]),
                                  "point": int(model.marker_of[g]) + 1, "error": float(e[g])},
                                 poses[int(model.pose_of[g])]) for g in order]
    return rec


def _with_source(entry: dict, pose: dict) -> dict:
    """``entry`` with ``where`` (the CSV file and line of an imported pose) where known."""
    if pose.get("source"):
        entry["where"] = pose["source"]
    return entry


def outside_record(model, poses, outside: dict, after, sel) -> dict:
    """The held-out poses outside the fitted range: which, why, and their errors."""
    groups = getattr(model, "row_group", None)
    if groups is not None:
        e = model.point_errors(after)
        rp = np.asarray(model.pose_of)
        es = e[np.isin(rp, sorted(outside))]
    else:
        es = np.abs(after[sel])
    return {"poses": [_with_source({"pose": int(poses[i]["index"]), "why": why}, poses[i])
                      for i, why in sorted(outside.items())],
            "rms": float(np.sqrt(np.mean(es ** 2))), "max": float(es.max())}


def in_fit_columns(model, result, W, idx) -> np.ndarray:
    """The rows ``idx`` of ``W`` (of ``model``, the validation poses' model) in the fit's
    columns: a parameter the validation model does not free (sm-plane's given plane)
    adds no uncertainty to the prediction."""
    out = np.zeros((len(idx), len(result.names)))
    for j, name in enumerate(model.names):
        if name in result.names:
            out[:, result.names.index(name)] = W[idx, j]
    return out


def heldout_outlier(outcome: BatchOutcome, model, raw, W_fit, idx) -> tuple | None:
    """The held-out row (of ``model``, the validation poses' model; ``raw`` its residual
    at the solution) whose prediction error is most significant against its prediction
    std, if beyond the Bonferroni threshold over the rows tested: ``(Outlier, rows
    tested)`` with the row of ``model``; else None. ``idx``: the rows tested, ``W_fit``
    their Jacobian in the fit's columns (:func:`in_fit_columns`). The noise and the
    parameters' covariance are the fit's. Rows read together (a point's x, y, z) are
    judged together."""
    fit, result = outcome.model, outcome.result
    channels = tuple(fit.channels)
    if any(ch not in channels for ch in model.channels) or not len(idx):
        return None
    rc = np.array([channels.index(model.channels[k]) for k in model.row_channel], dtype=int)
    groups = getattr(model, "row_group", None)
    if groups is not None:
        g = np.asarray(groups)[idx]
        _u, g = np.unique(g, return_inverse=True)
        cov, grows, dof = q.prediction_blocks(fit, result, W_fit, rc[idx], g)
        o, n_test = q.worst_prediction_group(np.asarray(raw)[idx], cov, grows, dof, rc[idx],
                                             channels)
    else:
        std, dof = q.prediction_std(fit, result, W_fit, rc[idx])
        o, n_test = q.worst_prediction(np.asarray(raw)[idx], std, dof, rc[idx], channels)
    if o is None:
        return None
    import dataclasses

    return dataclasses.replace(o, row=int(idx[o.row])), n_test


def _row_pose(model) -> np.ndarray | None:
    from station.fitting.gate import row_poses

    return row_poses(model)


def _in_metres(method: str, residual, x, robot):
    """sm-plane: the residual ``a x + b y + c z + 1`` of a contact as its distance (m)
    from the plane of ``x``; others unchanged."""
    if method != "sm-plane":
        return residual
    return residual / np.linalg.norm(np.asarray(x, dtype=float)[robot.n_params:])


def _unit(method: str, channel: str) -> str:
    if channel in ("distance", "x", "y", "z", "dx", "dy", "plane", "marker"):
        return "m"
    if method == "pm-ik":
        return "actuator units"
    return "rad"
