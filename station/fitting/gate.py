"""The fit-quality gate: every calibration (batch, session, GUI) passes it in
:func:`station.fitting.batch.calibrate` before a parameter file can be written.

1. Outliers: the reading with the largest externally studentized residual
   (:mod:`calibration.quality`) beyond the Bonferroni threshold is named by its
   pose index and channel, its pose is left out and the trace refitted; repeated
   while one is found, up to :func:`max_outliers`. sm-markers: a pose's points are
   judged as one block, by what the pose does to the fit
   (:mod:`station.fitting.pose_outliers`).
2. Noise: per channel with a stated ``sigma`` (trace header), the residual must
   fit that noise (chi-square, upper tail).
3. Validation: where the trace holds held-out poses, the calibrated parameters
   must not predict them worse than the start values did, and no held-out
   reading may be beyond its own prediction std (noise plus the parameters'
   uncertainty, Bonferroni over the held-out rows:
   :func:`calibration.quality.worst_prediction`).
4. Spread: the fit poses must hold enough distinct poses for the identifiable
   parameters (eq. 60), and the method must identify what a well-spread set of
   poses identifies (:func:`station.fitting.pose_count.parameter_count`).

A failed gate raises :class:`~station.fitting.verdict.FitQualityError` (with the outcome, so that a GUI
can still show it) unless the operator accepts the fit explicitly; the result
goes into the parameter file as ``fit.quality``.
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np

from calibration import identifiability as ident
from calibration import quality as q
from calibration import robust_fit
from calibration.errors import CalibrationError
from station.fitting.gate_checks import (check_explains, check_plausibility, check_poses,
                                         check_validation, people)
from station.fitting.point_check import check_points
from station.fitting.pose_count import NR_P, parameter_count
from station.fitting.pose_outliers import (MAX_RESTARTS, applies, judge_poses, lower,
                                           model_error)
from station.fitting.verdict import (OUTLIER_MODES, FitQualityError, NotConverged, Quality,
                                     describe, max_outliers, stops_judging)


def point_of_row(model, row: int) -> int | None:
    """The point on the tool (1-based) a residual row of sm-markers reads, else None."""
    groups, marker = getattr(model, "row_group", None), getattr(model, "marker_of", None)
    if groups is None or marker is None:
        return None
    return int(marker[int(groups[row])]) + 1


def row_poses(model) -> np.ndarray | None:
    """For each residual row, the position of its pose among the model's poses
    (sm-self-redundancy: the second pose of the pair); None if unknown."""
    if getattr(model, "row_pose", None) is not None:
        return np.asarray(model.row_pose)
    rows = len(model.row_channel)
    if hasattr(model, "other") and hasattr(model, "n_pose_rows"):
        return np.repeat(np.asarray(model.other), rows // max(model.n_pose_rows, 1))
    n = model.n_poses
    if n and rows % n == 0:
        return np.repeat(np.arange(n), rows // n)
    return None


def _excluded(trace, indices: set[int]):
    """A copy of ``trace`` whose poses with these indices are left out of the fit
    (``use = "outlier"``); sm-self-redundancy also leaves out a pair's lone partner."""
    poses = [dict(p, use="outlier") if p["index"] in indices else p for p in trace.poses]
    partners = []
    if trace.method == "sm-self-redundancy":
        count: dict = {}
        for p in poses:
            if p.get("use", "fit") == "fit":
                count[p["group"]] = count.get(p["group"], 0) + 1
        for k, p in enumerate(poses):
            if p.get("use", "fit") == "fit" and count[p["group"]] < 2:
                poses[k] = dict(p, use="outlier")
                partners.append(p["index"])
    return dataclasses.replace(trace, poses=poses), partners


def _entry(trace, model, row: q.Outlier, rows_tested: int | None = None) -> dict:
    pose = trace.fit_poses[int(row_poses(model)[row.row])]
    e = {"pose": int(pose["index"]), "channel": row.channel, "residual": row.residual,
         "t": row.t, "threshold": row.threshold}
    if pose.get("source"):
        e["where"] = pose["source"]
    point = point_of_row(model, row.row)
    if point is not None:
        e["point"] = point
    if rows_tested is not None:
        e["rows_tested"] = rows_tested
    return e


def _free_at(model, x, fixed) -> np.ndarray:
    """The parameters a fit from ``x`` calibrates: not ``fixed`` and identifiable
    there (structurally, in the model's identification order)."""
    cand = np.array([n not in set(fixed) for n in model.names])
    try:
        W = model.evaluate(np.asarray(x, dtype=float))[1]
    except CalibrationError:
        return cand
    return ident.classify(W, candidates=cand, order=model.identify_order)[0]


def held_at_start(model, fixed=()) -> tuple[str, ...]:
    """What every fit of the gate holds at its start values: the ``fixed`` parameters and
    those the model cannot identify at its start values (a zero column, or a column that
    is a combination of earlier ones). A refit started from a solution must not free
    them: there a dependency can be broken by a hair (a joint tilted by a milliradian
    makes its zero a hair independent of the instrument frame's turn) and the refit
    crawls along the flat valley for its whole iteration budget; and a robust fit that
    moves them moves what the station reports as held."""
    free = _free_at(model, model.x0, fixed)
    return tuple(n for n, f in zip(model.names, free) if not f)


def _free(model, hold) -> np.ndarray:
    held = set(hold)
    return np.array([n not in held for n in model.names])


def rescue(trace, model, error: NotConverged, *, refit, stated_sigma: dict | None,
           hold=()):
    """A fit that did not converge: leave out the readings a robust fit rejects
    (:func:`calibration.robust_fit.robust_worst_row`), one at a time, until the fit
    converges. Returns ``(trace, model, result, outliers)``; raises ``error`` (with
    the suspects named) if that does not help."""
    outliers: list[dict] = []
    limit = max_outliers(len(trace.fit_poses))
    while len(outliers) < limit and row_poses(model) is not None:
        worst, x_robust = robust_fit.robust_worst_row(model, model.x0, stated_sigma,
                                             free=_free(model, hold))
        if worst is None:
            break
        entry = dict(_entry(trace, model, worst), test="robust fit")
        excl = {o["pose"] for o in outliers} | {entry["pose"]}
        for o in outliers:
            excl |= set(o.get("partners", ()))
        new_trace, partners = _excluded(trace, excl)
        if partners:
            entry["partners"] = partners
        outliers.append(entry)
        try:
            model, result = refit(new_trace, x_robust, hold=hold)
            return new_trace, model, result, outliers
        except NotConverged as e:
            trace, model = new_trace, e.model
        except CalibrationError:
            break
    if outliers:
        named = ", ".join(f"{describe(o)} ({o['t']:.3g} robust sigmas)" for o in outliers)
        raise CalibrationError(f"{error}; readings that do not fit a robust fit: {named}; "
                               f"check them (the fit does not converge without them either)")
    raise error


def check_spread(trace, model) -> None:
    """Before fitting: refuse a set of poses with fewer distinct poses than eq. 60
    asks for the parameters the method identifies (e.g. all poses identical)."""
    qm = getattr(model, "qm", None)
    if qm is None or trace.method not in NR_P or "robot_file" in trace.header:
        return    # NR_P counts AGEBOT's parameters
    need = min(ident.minimum_poses(parameter_count(trace.method, trace.distance_zero), model.p),
               model.n_poses)
    distinct = q.distinct_poses(qm)
    if distinct < need:
        raise FitQualityError(f"the fit failed the quality gate: poses: only {distinct} distinct "
                              f"of {model.n_poses} poses to fit; {trace.method} needs {need} "
                              f"distinct poses (eq. 60): the robot did not move between readings")


def gated_fit(trace, model, *, first, refit, stated_sigma, validate, fixed=(),
              outlier_mode: str = "exclude"):
    """The gate around a calibration: ``first()`` fits ``model`` (raising a
    :class:`CalibrationError` with ``.model`` if it does not converge),
    ``refit(trace, start, hold=names)`` fits a trace copy from ``start`` holding
    ``hold`` (:func:`held_at_start`: ``fixed`` and what the model cannot identify at its
    start values), as every refit and robust fit of the gate does. Returns ``(quality, trace, model,
    result, validation)`` of the fit that passed, else of the last one tried.
    ``outlier_mode``: ``exclude`` (leave a reading that does not fit out and refit),
    ``flag`` (name the worst, keep it in the fit) or ``off`` (not judged); the noise,
    validation and plausibility checks judge the fit in every mode."""
    if outlier_mode not in OUTLIER_MODES:
        raise CalibrationError(f"outliers: {outlier_mode!r} is not one of "
                               f"{', '.join(OUTLIER_MODES)}")
    check_spread(trace, model)
    hold = held_at_start(model, fixed)
    try:
        model0, result = first()
        pre = []
    except NotConverged as e:
        trace, model0, result, pre = rescue(trace, model, e, refit=refit, stated_sigma=stated_sigma,
                                            hold=hold)
    got = run_gate(trace, model0, result, refit=refit, stated_sigma=stated_sigma,
                   validate=validate, outliers=pre, hold=hold, mode=outlier_mode)
    quality, trace1, model1 = got[:3]
    quality.outlier_mode = outlier_mode
    if outlier_mode != "exclude":
        return got          # (the robust phase leaves readings out)
    if quality.passed or len(quality.outliers) >= max_outliers(len(trace.fit_poses)) \
            or any(c["check"] == "points" and not c["ok"] for c in quality.checks):
        return got          # (a point off the tool is no reading to leave out)
    # least squares may spread a gross reading over every residual: ask a robust fit,
    # started where least squares ended (from the bare start values a robot far from
    # its nominal lands in another minimum, where every reading looks gross)
    worst, x_robust = robust_fit.robust_worst_row(model1, got[3].x, stated_sigma,
                                         free=_free(model1, hold))
    if worst is None and x_robust is not None:
        # no gross reading: least squares found a local minimum; start again where
        # the robust fit ended
        try:
            model2, result2 = refit(trace1, x_robust, hold=hold)
        except CalibrationError:
            return got
        got2 = run_gate(trace1, model2, result2, refit=refit, stated_sigma=stated_sigma,
                        validate=validate, outliers=quality.outliers, hold=hold)
        if got2[0].passed or lower(got2[2:4], got[2:4]):
            # a lower minimum is the fit to judge (and to name what fails in it)
            got2[0].check("start", True, "start: the fit from the start values ended in a "
                          "local minimum; refitted from a robust fit's solution")
            return got2
        return got
    if worst is None or row_poses(model1) is None:
        return got
    entry = dict(_entry(trace1, model1, worst), test="robust fit")
    excl = {entry["pose"]}
    for o in quality.outliers:
        excl |= {o["pose"], *o.get("partners", ())}
    new_trace, partners = _excluded(trace1, excl)
    if partners:
        entry["partners"] = partners
    try:
        model2, result2 = refit(new_trace, x_robust, hold=hold)
    except CalibrationError:
        quality.check("outliers", False, f"outliers: {describe(entry)} does "
                      f"not fit a robust fit ({worst.t:.3g} robust sigmas) and the fit without it "
                      "does not converge", next=entry)
        return got
    got2 = run_gate(new_trace, model2, result2, refit=refit, stated_sigma=stated_sigma,
                    validate=validate, outliers=[*quality.outliers, entry], hold=hold)
    if not got2[0].passed:
        got2[0].check("outliers", False, f"outliers: {describe(entry)} "
                      f"does not fit a robust fit ({worst.t:.3g} robust sigmas), and the fit "
                      "still fails without it", next=entry)
    return got2


def _confirmed(model, model_without, result_without, worst: q.Outlier) -> bool:
    """Is the suspect reading also an outlier against the fit made without its pose
    (``model_without``, ``result_without``): its prediction error there in its own
    std, the noise of that fit plus its parameters' uncertainty at that row
    (:func:`calibration.quality.prediction_std`; a high-leverage row's prediction
    is the less certain), against the same threshold? A reading of several rows (a
    point's x, y, z) is judged whole (:func:`calibration.quality.prediction_blocks`)."""
    groups = getattr(model, "row_group", None)
    try:
        r, W = model.evaluate(result_without.x)
        if groups is not None:
            rows = np.flatnonzero(np.asarray(groups) == groups[worst.row])
            rc = np.asarray(model.row_channel)[rows]
            cov, _rows, _dof = q.prediction_blocks(model_without, result_without, W[rows], rc,
                                                   np.zeros(len(rows), dtype=int))
            e = r[rows]
            t2 = float(e @ np.linalg.solve(cov[0], e))
            return not math.isfinite(t2) or math.sqrt(max(t2, 0.0)) > worst.threshold
        rc = np.asarray(model.row_channel)[[worst.row]]
        std = q.prediction_std(model_without, result_without, W[[worst.row]], rc)[0][0]
    except (CalibrationError, np.linalg.LinAlgError):
        return True
    if not std > 0 or not math.isfinite(std):
        return True
    return abs(float(r[worst.row])) > worst.threshold * std


def _worst(model, result):
    """The most significant fit reading (:func:`calibration.quality.worst_row`, or
    :func:`calibration.quality.worst_group` where the rows come in groups read
    together) and the number tested."""
    r, W = model.evaluate(result.x)
    active = np.array([s.identifiable for s in result.status])
    w = q.row_weights(model.row_channel, model.channels, result.sigma)
    groups = getattr(model, "row_group", None)
    if groups is None:
        return q.worst_row(r, q.leverage(W, w, active), model.row_channel, model.channels)
    return q.worst_group(r, q.hat_basis(W, w, active), w, model.row_channel, model.channels,
                         groups)


def _statistics(model, result):
    r, W = model.evaluate(result.x)
    active = np.array([s.identifiable for s in result.status])
    w = q.row_weights(model.row_channel, model.channels, result.sigma)
    h = q.leverage(W, w, active)
    return r, h


def run_gate(trace, model, result, *, refit, stated_sigma: dict | None,
             validate=None, outliers=(), hold=(), mode: str = "exclude"):
    """Run the gate on a converged fit. ``refit(trace, start, hold=names) -> (model, result)``
    calibrates a trace copy from the start values ``start`` (the fit's so far); ``validate(trace, model, result)`` gives the held-out rows
    (:func:`station.fitting.validation.validation_errors`). Returns ``(quality, trace,
    model, result, validation)``, the last four those of the final fit."""
    quality = Quality(outliers=list(outliers))
    excluded: set[int] = set()
    for o in outliers:
        excluded |= {o["pose"], *o.get("partners", ())}
    limit = max_outliers(len(trace.fit_poses) + len(excluded))
    restarts, blocks = 0, applies(model)   # sm-markers: a pose's points judged as one block
    if blocks and mode != "off":
        trace, model, result, restarts = judge_poses(
            quality, trace, model, result, refit=refit, hold=hold, mode=mode, limit=limit,
            stated_sigma=stated_sigma, excluded=excluded, exclude_from=_excluded)
    while not blocks:
        if mode == "off" or row_poses(model) is None:
            break                       # (off: not judged, nothing to compute)
        worst, n_test = _worst(model, result)
        if worst is None:
            break
        entry = _entry(trace, model, worst, n_test)
        said = f"studentized residual {worst.t:.3g} > {worst.threshold:.3g}"
        if stops_judging(quality, mode, entry, said, limit, "readings"):
            break
        new_trace, partners = _excluded(trace, excluded | {entry["pose"]})
        try:
            new_model, new_result = refit(new_trace, result.x, hold=hold)
        except CalibrationError as e:
            quality.check("outliers", False, f"outliers: {describe(entry)} does not fit "
                          f"({said}) and the fit without it fails: {e}", next=entry)
            break
        if restarts < MAX_RESTARTS and not _confirmed(model, new_model, new_result, worst):
            # the reading fits the fit made without it: the first fit was in a local
            # minimum, not thrown off by this reading; refit every pose from there
            try:
                model, result = refit(trace, new_result.x, hold=hold)
            except CalibrationError:
                pass
            restarts += 1
            continue
        if partners:
            entry["partners"] = partners
        quality.outliers.append(entry)
        excluded |= {entry["pose"], *partners}
        trace, model, result = new_trace, new_model, new_result
    if restarts:
        quality.check("start", True, f"start: {restarts} local minimum(s) left by refitting "
                      "from the fit without a suspect reading (which then fitted the others)")
    if mode == "off":
        quality.check("outliers", True, "outliers: not judged (--outliers off)")
    failed = any(c["check"] == "outliers" and not c["ok"] for c in quality.checks)
    if quality.outliers and not failed:    # (a failure names the excluded ones already)
        how = "" if blocks else " (a reading that does not fit takes its whole pose out)"
        quality.check("outliers", True, f"outliers: {len(quality.outliers)} pose(s) excluded"
                      f"{how} and the trace refitted: "
                      + ", ".join(describe(o) for o in quality.outliers))
    elif not any(c["check"] == "outliers" for c in quality.checks) and mode != "off":
        quality.check("outliers", True, "outliers: none")
    r, h = _statistics(model, result)
    real = model_error(quality)   # sm-markers: residuals set by the model, not the instrument
    for c in q.chi_square(r, h, model.row_channel, model.channels, stated_sigma or {}):
        verdict, note = ("fit", "") if c["ok"] else ("do not fit", real)
        quality.check("noise", c["ok"] or bool(note),
                      f"noise: {c['channel']} residuals {verdict} the stated sigma "
                      f"{people(c['stated_sigma'], c['channel'])} (fitted "
                      f"{people(c['fitted_sigma'], c['channel'])}, "
                      f"{c['ratio']:.3g} times; chi-square {c['chi2']:.4g} on {c['dof']:.1f} "
                      f"degrees of freedom, p = {c['p']:.2g}){note}", short=bool(note),
                      **{k: c[k] for k in ("channel", "stated_sigma", "fitted_sigma", "ratio",
                                           "chi2", "dof", "p")})
    check_poses(quality, trace, model, result)
    serial = "robot_file" in trace.header   # robot files and URDF robots (else AGEBOT's)
    check_plausibility(quality, model, result, trace.method, serial)
    if serial:
        check_explains(quality, model, result)
        check_points(quality, trace, model, result, refit=refit, hold=hold)
    validation = None
    if validate is not None and trace.validation_poses:
        validation = validate(trace, model, result)
        check_validation(quality, validation)
    return quality, trace, model, result, validation
