"""Outliers judged per pose by what the pose does to the fit (issue 42; sm-markers,
whose poses read several points together).

A pose's rows are one block. Its deleted residual ``(I - H_ii)^-1 r_i`` is its error
from the fit made without it (``H_ii`` its block of the hat matrix of the whitened,
scaled Jacobian at the solution), so an influential pose is not hidden by the fit it
distorts; its Mahalanobis size against ``s^2 (I - H_ii)^-1`` is the externally
studentized statistic of :func:`calibration.pose_quality.pose_blocks`.

The threshold is the noise's (Bonferroni over the poses) where the residuals are the
instrument's noise. Where they are not (a channel's fitted sigma far above the stated
one, or the poses' sizes spread far wider than noise spreads them: real data, where
what the geometric model cannot describe sets the residuals), a pose must also stand
out of the level the data show (:func:`calibration.pose_quality.robust_level`), said in one
line.

A pose beyond the threshold is left out only if the fit without it (refitted once)
predicts the other poses better: their deleted residuals, each pose predicted by a fit
that did not see it, against the same with the pose in the fit. (Their plain residual
always drops when a pose leaves a least-squares fit.) Else it is kept, and said so.
Every excluded pose's error under the final model is kept in its entry.
"""
from __future__ import annotations

import math

import numpy as np

from calibration import pose_quality as pq
from calibration import quality as q
from calibration.errors import CalibrationError
from station.fitting.verdict import describe, stops_judging

#: the poses' sizes spread this many times wider than noise spreads them: model error
MODEL_ERROR_SPREAD = 1.5
#: a channel's fitted sigma this many times its stated one: model error
MODEL_ERROR_RATIO = 3.0
#: refits of every pose from a better start that one judgment may make
MAX_RESTARTS = 3


def applies(model) -> bool:
    """Are ``model``'s poses judged as blocks (rows of points read together, per pose)?"""
    return getattr(model, "row_group", None) is not None and \
        getattr(model, "row_pose", None) is not None


def _blocks(model, result):
    r, W = model.evaluate(result.x)
    active = np.array([s.identifiable for s in result.status])
    w = q.row_weights(model.row_channel, model.channels, result.sigma)
    U = q.hat_basis(W, w, active, overwrite=True)    # U in W's own rows (a large fit)
    del W
    return r, w, pq.pose_blocks(r, U, w, model.row_pose), np.einsum("ij,ij->i", U, U)


def _index(trace, b) -> int:
    return int(trace.fit_poses[b.pose]["index"])


def _point_3d(v) -> float:
    """A per-row figure of x, y, z rows as one point's 3D figure."""
    return v * math.sqrt(3.0)


def model_error_level(model, r, h, blocks, stated_sigma) -> dict | None:
    """The level the data show (:func:`calibration.pose_quality.robust_level`, its ``why``)
    where the residuals are not the instrument's noise, else None."""
    if len(blocks) < 5:
        return None
    level = pq.robust_level([b.size for b in blocks], [len(b.rows) for b in blocks])
    level["sigma"] = math.sqrt(float(r @ r) / max(len(r) - float(np.sum(h)), 1.0))
    why = []
    for c in q.chi_square(r, h, model.row_channel, model.channels, stated_sigma or {}):
        if c["ratio"] > MODEL_ERROR_RATIO:
            why.append(f"the residuals {c['ratio']:.3g} times the stated sigma")
    if level["spread"] > MODEL_ERROR_SPREAD:
        why.append(f"the poses spread {level['spread']:.3g} times as widely as noise "
                   "spreads them")
    if not why:
        return None
    return dict(level, why="; ".join(why))


def _entry(trace, model, r, b) -> dict:
    pose = trace.fit_poses[b.pose]
    errs = np.linalg.norm(b.deleted.reshape(-1, 3), axis=1)
    j = int(np.argmax(errs))
    e = {"pose": int(pose["index"]), "channel": model.channels[model.row_channel[b.rows[0]]],
         "residual": float(np.linalg.norm(r[b.rows].reshape(-1, 3), axis=1).max()),
         "t": b.t, "threshold": b.threshold, "test": "deleted residual",
         "deleted": float(errs[j]), "leverage": b.leverage, "size": _point_3d(b.size)}
    if pose.get("source"):
        e["where"] = pose["source"]
    marker = getattr(model, "marker_of", None)
    if marker is not None:
        e["point"] = int(marker[int(model.row_group[b.rows[3 * j]])]) + 1
    return e


def _press(trace, blocks, leave: int) -> dict:
    """Each pose's squared deleted residual (by trace index), but ``leave``'s."""
    return {_index(trace, b): (float(b.deleted @ b.deleted), len(b.rows)) for b in blocks
            if _index(trace, b) != leave}


def lower(a, b) -> bool:
    """Does the fit ``a = (model, result)`` end lower than ``b`` on the same trace
    (both residuals weighted with ``b``'s sigma)?"""
    (_, ra), (mb, rb) = a, b
    w = q.row_weights(mb.row_channel, mb.channels, rb.sigma)
    return float(np.sum(w * ra.residual ** 2)) < float(np.sum(w * rb.residual ** 2))


def _cost(model, x, w) -> float:
    return float(np.sum(w * model.evaluate(x)[0] ** 2))


def judge_poses(quality, trace, model, result, *, refit, hold, mode: str, stated_sigma,
                excluded: set, limit: int, exclude_from):
    """Judge ``model``'s poses as blocks (see the module); ``exclude_from(trace,
    indices) -> (trace, partners)`` leaves poses out of a trace copy. Appends to
    ``quality`` (``outliers`` and checks) and ``excluded``; returns ``(trace, model,
    result, restarts)`` of the final fit."""
    trace_all, model_all, restarts, kept = trace, model, 0, set()
    r, w, blocks, h = _blocks(model, result)
    level = model_error_level(model, r, h, blocks, stated_sigma)
    start, used = len(quality.outliers), level
    while True:
        cands = sorted((b for b in blocks if b.t > b.threshold and _index(trace, b) not in kept
                        and (mode != "flag" or level is None or b.size > level["limit"])),
                       key=lambda b: (b.p, -b.size) if level is None else (-b.size,))
        if not cands or len(kept) > limit:    # (each pose tried costs a refit)
            break
        b = cands[0]
        entry = _entry(trace, model, r, b)
        said = (f"{entry['deleted'] * 1e3:.4g} mm from the prediction of the fit without "
                f"it, studentized {b.t:.3g} > {b.threshold:.3g}")
        if stops_judging(quality, mode, entry, said, limit, "poses"):
            break
        new_trace, partners = exclude_from(trace, excluded | {entry["pose"]})
        try:
            new_model, new_result = refit(new_trace, result.x, hold=hold)
        except CalibrationError as e:
            quality.check("outliers", False, f"outliers: {describe(entry)} does not fit "
                          f"({said}) and the fit without it fails: {e}", next=entry)
            break
        if restarts < MAX_RESTARTS and _cost(model, new_result.x, w) < _cost(model, result.x, w):
            # the fit without the pose fits every pose better, the pose too: the fit was
            # in a local minimum, not thrown off by this pose; refit every pose from there
            try:
                model, result = refit(trace, new_result.x, hold=hold)
                r, w, blocks, h = _blocks(model, result)
                level = model_error_level(model, r, h, blocks, stated_sigma)
                model_all, used = model, level
            except CalibrationError:
                pass
            restarts += 1
            continue
        _r2, _w2, blocks2, h2 = _blocks(new_model, new_result)
        if level is not None:
            # judged against the level the other poses show, from the fit without it
            # (a gross reading smears into the others' residuals and widens theirs)
            used = model_error_level(new_model, _r2, h2, blocks2, stated_sigma) or used
            if not b.size > used["limit"]:
                break       # within the level: so is every smaller pose
            entry["level"] = _point_3d(used["limit"])
        after = _press(new_trace, blocks2, entry["pose"])
        before = _press(trace, blocks, entry["pose"])
        common = sorted(set(after) & set(before))
        rows = max(sum(before[i][1] for i in common), 1)
        was, now = (_point_3d(math.sqrt(sum(d[i][0] for i in common) / rows))
                    for d in (before, after))
        entry["others"] = [was, now]
        if not now < was:
            kept.add(entry["pose"])
            quality.check("outliers", True, f"outliers: {describe(entry)} kept: {said}, but "
                          f"the fit without it predicts the others no better ({was * 1e3:.3g} "
                          f"-> {now * 1e3:.3g} mm, each by a fit without it)", kept=entry)
            continue
        if partners:
            entry["partners"] = partners
        quality.outliers.append(entry)
        excluded |= {entry["pose"], *partners}
        trace, model, result = new_trace, new_model, new_result
        r, w, blocks, _h = _blocks(model, result)
    _final_errors(quality.outliers[start:], trace_all, model_all, result)
    if used is not None:
        quality.check("outliers", True, "outliers: judged at the model-error level the data "
                      f"show: {_point_3d(used['median']) * 1e3:.3g} mm per point (the poses' "
                      "deleted residuals, studentized: median), an outlier beyond "
                      f"{_point_3d(used['limit']) * 1e3:.3g} mm ({used['why']})",
                      level={k: used[k] for k in ("median", "limit", "spread", "poses",
                                                  "sigma")})
    return trace, model, result, restarts


def model_error(quality) -> str:
    """Where the poses' deleted residuals spread far wider than noise spreads them (the
    outliers' level check), what the noise check adds: the residuals are the model's
    error, not the instrument's noise; else ``""``."""
    level = next((c["level"] for c in quality.checks if c.get("level")), None)
    if not level or level["spread"] <= MODEL_ERROR_SPREAD:
        return ""
    return (f"; the poses spread {level['spread']:.3g} times as widely as noise spreads them: "
            "what the geometric model cannot describe sets the residuals, not the instrument "
            "(outliers judged at that level)")


def _final_errors(entries, trace_all, model_all, result) -> None:
    """Each excluded pose's largest point error under the final model (``final``, m)."""
    if not entries:
        return
    try:
        r = model_all.evaluate(result.x)[0]
    except CalibrationError:
        return
    pos = {int(p["index"]): k for k, p in enumerate(trace_all.fit_poses)}
    rp = np.asarray(model_all.row_pose)
    for e in entries:
        k = pos.get(e["pose"])
        if k is None:
            continue
        rows = np.flatnonzero(rp == k)
        if len(rows):
            e["final"] = float(np.linalg.norm(r[rows].reshape(-1, 3), axis=1).max())
