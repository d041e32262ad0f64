"""The fit-quality gate: every calibration (batch, session, GUI) passes it in
:func:`station.fitting.batch.calibrate` before a parameter file can be written.

1. Outliers: the reading with the largest externally studentized residual
   (:mod:`calibration.quality`) beyond the Bonferroni threshold is named by its
   pose index and channel, its pose is left out and the trace refitted; repeated
   while one is found, up to :func:`max_outliers`.
2. Noise: per channel with a stated ``sigma`` (trace header), the residual must
   fit that noise (chi-square, upper tail).
3. Validation: where the trace holds held-out poses, the calibrated parameters
   must not predict them worse than the start values did, and no held-out
   reading may be beyond its own prediction std (noise plus the parameters'
   uncertainty, Bonferroni over the held-out rows:
   :func:`calibration.quality.worst_prediction`).
4. Spread: the fit poses must hold enough distinct poses for the identifiable
   parameters (eq. 60), and the method must identify what a well-spread set of
   poses identifies (:func:`station.planning.arm_plan.parameter_count`).

A failed gate raises :class:`FitQualityError` (with the outcome, so that a GUI
can still show it) unless the operator accepts the fit explicitly; the result
goes into the parameter file as ``fit.quality``.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

import numpy as np

from calibration import identifiability as ident
from calibration import quality as q
from calibration.errors import CalibrationError

# The calibrated fit may predict the held-out poses at most this much worse than
# the start values before the gate calls it worse (noise on an already good start).
VALIDATION_TOLERANCE = 1.1


class FitQualityError(CalibrationError):
    """The fit failed the quality gate; ``outcome`` holds it (not written)."""

    def __init__(self, message: str, outcome=None):
        super().__init__(message)
        self.outcome = outcome


class NotConverged(CalibrationError):
    """The calibration did not converge; ``model`` is the measurement model tried."""

    def __init__(self, message: str, model=None):
        super().__init__(message)
        self.model = model


@dataclass
class Quality:
    """The gate's result (``fit.quality`` of the parameter file)."""

    outliers: list[dict] = field(default_factory=list)
    checks: list[dict] = field(default_factory=list)
    accepted: bool = False
    excluded: list[dict] = field(default_factory=list)   # by the operator: pose, reason

    @property
    def passed(self) -> bool:
        return all(c["ok"] for c in self.checks)

    @property
    def failures(self) -> list[str]:
        return [c["message"] for c in self.checks if not c["ok"]]

    def check(self, name: str, ok: bool, message: str, **figures) -> None:
        self.checks.append({"check": name, "ok": bool(ok), "message": message, **figures})

    def as_dict(self) -> dict:
        out = {"passed": self.passed, "accepted": self.accepted,
               "outliers": [dict(o) for o in self.outliers],
               "checks": [dict(c) for c in self.checks]}
        if self.excluded:
            out["excluded"] = [dict(e) for e in self.excluded]
        return out

    def lines(self) -> list[str]:
        """Human-readable lines (CLI table, GUI)."""
        out = [f"excluded by the operator: pose {e['pose']} ({e['reason']})"
               for e in self.excluded]
        for o in self.outliers:
            res = (f"{o['residual'] * 1e3:.4g} mm from its prediction" if "point" in o
                   else f"residual {o['residual']:.4g}")
            out.append(f"outlier excluded: {describe(o)} ({res}, studentized {o['t']:.3g} > "
                       f"{o['threshold']:.3g})")
        for c in self.checks:
            out.append(("ok: " if c["ok"] else "FAILED: ") + c["message"])
        if not self.passed:
            out.append("fit quality: FAILED" + (", accepted by the operator (--accept-poor-fit)"
                                                 if self.accepted else ""))
        else:
            out.append("fit quality: passed")
        return out

    def summary(self) -> str:
        """One line: what failed, with its figures."""
        return "; ".join(self.failures) if self.failures else "passed"


def max_outliers(n_poses: int) -> int:
    """At most one pose in ten (at least one) may be excluded as an outlier."""
    return max(1, n_poses // 10)


def point_of_row(model, row: int) -> int | None:
    """The point on the tool (1-based) a residual row of sm-markers reads, else None."""
    groups, marker = getattr(model, "row_group", None), getattr(model, "marker_of", None)
    if groups is None or marker is None:
        return None
    return int(marker[int(groups[row])]) + 1


def describe(o: dict) -> str:
    """``pose 5 marker`` (sm-markers: ``pose 5 point 2``) for an outlier entry."""
    return f"pose {o['pose']} point {o['point']}" if "point" in o else \
        f"pose {o['pose']} {o['channel']}"


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
    (:func:`calibration.quality.robust_worst_row`), one at a time, until the fit
    converges. Returns ``(trace, model, result, outliers)``; raises ``error`` (with
    the suspects named) if that does not help."""
    outliers: list[dict] = []
    limit = max_outliers(len(trace.fit_poses))
    while len(outliers) < limit and row_poses(model) is not None:
        worst, x_robust = q.robust_worst_row(model, model.x0, stated_sigma,
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
    from station.planning.arm_plan import NR_P, parameter_count

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


def gated_fit(trace, model, *, first, refit, stated_sigma, validate, fixed=()):
    """The gate around a calibration: ``first()`` fits ``model`` (raising a
    :class:`CalibrationError` with ``.model`` if it does not converge),
    ``refit(trace, start, hold=names)`` fits a trace copy from ``start`` holding
    ``hold`` (:func:`held_at_start`: ``fixed`` and what the model cannot identify at its
    start values), as every refit and robust fit of the gate does. Returns ``(quality, trace, model,
    result, validation)`` of the fit that passed, else of the last one tried."""
    check_spread(trace, model)
    hold = held_at_start(model, fixed)
    try:
        model0, result = first()
        pre = []
    except NotConverged as e:
        trace, model0, result, pre = rescue(trace, model, e, refit=refit, stated_sigma=stated_sigma,
                                            hold=hold)
    got = run_gate(trace, model0, result, refit=refit, stated_sigma=stated_sigma,
                   validate=validate, outliers=pre, hold=hold)
    quality, trace1, model1 = got[:3]
    if quality.passed or len(quality.outliers) >= max_outliers(len(trace.fit_poses)):
        return got
    # least squares may spread a gross reading over every residual: ask a robust fit,
    # started where least squares ended (from the bare start values a robot far from
    # its nominal lands in another minimum, where every reading looks gross)
    worst, x_robust = q.robust_worst_row(model1, got[3].x, stated_sigma,
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
        if got2[0].passed or _lower(got2[2:4], got[2:4]):
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


def _lower(a, b) -> bool:
    """Does the fit ``a = (model, result)`` end lower than ``b`` on the same trace
    (both residuals weighted with ``b``'s sigma)?"""
    (ma, ra), (mb, rb) = a, b
    w = q.row_weights(mb.row_channel, mb.channels, rb.sigma)
    return float(np.sum(w * ra.residual ** 2)) < float(np.sum(w * rb.residual ** 2))


# Refits of every pose from a better start that one run of the gate may make.
MAX_RESTARTS = 3


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
             validate=None, outliers=(), hold=()):
    """Run the gate on a converged fit. ``refit(trace, start, hold=names) -> (model, result)``
    calibrates a trace copy from the start values ``start`` (the fit's so far); ``validate(trace, model, result)`` gives the held-out rows
    (:func:`station.fitting.validation.validation_errors`). Returns ``(quality, trace,
    model, result, validation)``, the last four those of the final fit."""
    quality = Quality(outliers=list(outliers))
    excluded: set[int] = set()
    for o in outliers:
        excluded |= {o["pose"], *o.get("partners", ())}
    limit = max_outliers(len(trace.fit_poses) + len(excluded))
    restarts = 0
    while True:
        if row_poses(model) is None:
            break
        worst, n_test = _worst(model, result)
        if worst is None:
            break
        entry = _entry(trace, model, worst, n_test)
        if len(quality.outliers) >= limit:
            named = ", ".join(describe(o) for o in quality.outliers)
            quality.check("outliers", False,
                          f"outliers: more than {limit} readings do not fit the others "
                          f"({named + ', ' if named else ''}{describe(entry)}: studentized "
                          f"residual {worst.t:.3g} > "
                          f"{worst.threshold:.3g})", limit=limit, next=entry)
            break
        new_trace, partners = _excluded(trace, excluded | {entry["pose"]})
        try:
            new_model, new_result = refit(new_trace, result.x, hold=hold)
        except CalibrationError as e:
            quality.check("outliers", False,
                          f"outliers: {describe(entry)} does not fit "
                          f"(studentized residual {worst.t:.3g} > {worst.threshold:.3g}) and the "
                          f"fit without it fails: {e}", next=entry)
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
    if quality.outliers:
        quality.check("outliers", True, f"outliers: {len(quality.outliers)} reading(s) excluded "
                      "and the trace refitted: " + ", ".join(
                          describe(o) for o in quality.outliers))
    elif not quality.checks:
        quality.check("outliers", True, "outliers: none")
    r, h = _statistics(model, result)
    for c in q.chi_square(r, h, model.row_channel, model.channels, stated_sigma or {}):
        verdict = "fit" if c["ok"] else "do not fit"
        quality.check("noise", c["ok"],
                      f"noise: {c['channel']} residuals {verdict} the stated sigma "
                      f"{_people(c['stated_sigma'], c['channel'])} (fitted "
                      f"{_people(c['fitted_sigma'], c['channel'])}, "
                      f"{c['ratio']:.3g} times; chi-square {c['chi2']:.4g} on {c['dof']:.1f} "
                      f"degrees of freedom, p = {c['p']:.2g})",
                      **{k: c[k] for k in ("channel", "stated_sigma", "fitted_sigma", "ratio",
                                           "chi2", "dof", "p")})
    _spread(quality, trace, model, result)
    if "robot_file" not in trace.header:    # AGEBOT's parameters, whose kinds are known
        _plausible(quality, model, result, trace.method)
    else:                                   # robot files and URDF robots
        _plausible_serial(quality, model, result)
        _explains(quality, model, result)
    validation = None
    if validate is not None and trace.validation_poses:
        validation = validate(trace, model, result)
        by_points = any(v.get("points") for v in validation)
        for v in validation:
            before, after = v.get("rms_before"), v.get("rms_after")
            pts = v.get("points")
            if by_points and not pts:
                continue              # points on the tool: judged once, by their 3D errors
            if pts:
                before, after = pts.get("rms_before"), pts.get("rms_after")
            if before is None or after is None or not math.isfinite(after):
                continue
            ok = after <= VALIDATION_TOLERANCE * before
            if pts:
                w = pts["worst"][0]
                verb = "went" if ok else "is worse than the start:"
                text = (f"validation: held-out points' 3D RMS {verb} "
                        f"{mm(pts.get('rms_before'))} -> {mm(pts['rms_after'])} mm "
                        f"(max {mm(pts['max_after'])} mm at pose {w['pose']} point {w['point']}; "
                        f"{pts['n']} points of {pts['poses']} poses)")
            else:
                text = (f"validation: {v['channel']} RMS on {v['n']} held-out rows "
                        f"{'went' if ok else 'is worse than the start:'} "
                        f"{_people(before, v['channel'], v['unit'])} -> "
                        f"{_people(after, v['channel'], v['unit'])}")
            extra = {"points": dict(pts)} if pts else {}
            quality.check("validation", ok, text, channel=v["channel"], rms_before=before,
                          rms_after=after, **extra)
        for v in validation:
            out = v.get("outside_range")
            if out:
                named = ", ".join(f"pose {p['pose']} ({p['why']})" for p in out["poses"][:3])
                more = f" and {len(out['poses']) - 3} more" if len(out["poses"]) > 3 else ""
                unit = "mm" if v.get("points") else v["unit"]
                fig = ((mm(out["rms"]), mm(out["max"])) if v.get("points")
                       else (f"{out['rms']:.4g}", f"{out['max']:.4g}"))
                quality.check("extrapolation", True,
                              f"validation: {len(out['poses'])} held-out pose(s) lie outside "
                              f"the fitted poses' joint ranges: {named}{more}; their errors "
                              f"(RMS {fig[0]}, max {fig[1]} {unit}) are an extrapolation, "
                              "reported and not judged", channel=v["channel"],
                              outside_range=out)
        for v in validation:
            o = v.get("outlier")
            if o:
                where = f"pose {o['pose']}" if o.get("pose") is not None else "a held-out pose"
                if "point" in o:
                    what = (f"validation: held-out {where} point {o['point']} is "
                            f"{mm(o['residual'])} mm off the calibration's prediction, "
                            f"{o['t']:.3g} times its predicted std (threshold "
                            f"{o['threshold']:.3g} over {o['rows_tested']} held-out points)")
                else:
                    what = (f"validation: held-out {where} {v['channel']} is "
                            f"{o['residual']:.4g} {v['unit']} off the calibration's "
                            f"prediction, {o['t']:.3g} times its predicted std {o['std']:.3g} "
                            f"{v['unit']} (threshold {o['threshold']:.3g} over "
                            f"{o['rows_tested']} held-out rows)")
                quality.check("validation", False, what + ": a bad reading or a model that "
                              "does not predict; check that pose's reading",
                              channel=v["channel"], heldout=dict(o))
    return quality, trace, model, result, validation


def _people(v, channel: str, si: str | None = None) -> str:
    """A channel's figure for people: mm and degrees with the unit (station.outputs.units)."""
    from station.outputs.units import MM_DEG, channel_si

    return MM_DEG.text(v, si if si is not None else channel_si(channel), ".4g")


def mm(v) -> str:
    """A length in metres as millimetres for people (``-`` where unknown)."""
    return "-" if v is None or not math.isfinite(v) else f"{v * 1e3:.3g}"


def _spread(quality, trace, model, result) -> None:
    from station.planning.arm_plan import NR_P, parameter_count

    qm = getattr(model, "qm", None)
    if qm is None:
        return
    distinct = q.distinct_poses(qm)
    n_id = result.n_identifiable
    need = ident.minimum_poses(n_id, model.p)
    expected = (parameter_count(trace.method, trace.distance_zero) if trace.method in NR_P
                else n_id)
    if "robot_file" in trace.header:
        expected = n_id    # NR_P counts AGEBOT's parameters
    if trace.method == "pm-fk" and trace.header.get("components"):
        expected = n_id    # fewer components may identify fewer parameters
    ok = distinct >= min(need, model.n_poses) and n_id >= expected
    why = ""
    if n_id < expected:
        why = (f"; only {n_id} of {len(result.names)} parameters are identifiable where a "
               f"well-spread set of poses identifies {expected}")
    quality.check("poses", ok, f"poses: {distinct} distinct of {model.n_poses} fitted "
                  f"(eq. 60 recommends >= {need} for {n_id} identifiable){why}",
                  distinct=distinct, poses=int(model.n_poses), identifiable=int(n_id),
                  expected_identifiable=int(expected))


# Calibrated gear ratios and lengths must stay within this factor of their start
# values (a sign flip or a halving is a mis-wired reading, not a robot).
PLAUSIBLE_FACTOR = 2.0


def _plausible(quality, model, result, method) -> None:
    """The robot's gear ratios (``k*``) and lengths keep their sign and stay within
    :data:`PLAUSIBLE_FACTOR` of the start; offsets, a method's extra parameters
    (plane, inclinometer mount) and sm-distance-tilt's frame (``a0``) are free."""
    frame = ("a0",) if method == "sm-distance-tilt" else ()
    robot = getattr(model, "robot", None)
    own = set(robot.param_names) if robot is not None else set()
    bad = []
    for j, (name, st) in enumerate(zip(result.names, result.status)):
        if (not st.identifiable or name.endswith("_off") or name.startswith(("theta", "plane_"))
                or name in frame or name not in own):
            continue
        x0, x = float(model.x0[j]), float(result.x[j])
        if x0 == 0 or not math.isfinite(x):
            continue
        ratio = x / x0
        if not 1 / PLAUSIBLE_FACTOR <= ratio <= PLAUSIBLE_FACTOR:
            bad.append((name, x0, x, ratio))
    if bad:
        quality.check("plausible", False, "plausible: " + ", ".join(
            f"{n} went from {a:.4g} to {b:.4g} ({r:.3g} times)" for n, a, b, r in bad)
            + f"; gear ratios and lengths move by less than a factor {PLAUSIBLE_FACTOR:g} on a "
            "real robot: a reading's sign, unit or word order is likely wrong",
            parameters=[{"name": n, "start": a, "calibrated": b} for n, a, b, _ in bad])
    else:
        quality.check("plausible", True, "plausible: gear ratios and lengths within a factor "
                      f"{PLAUSIBLE_FACTOR:g} of the start")


# A robot file's or URDF robot's calibration, against its start values: a joint's
# correction beyond these is a wrong unit, sign, zero or robot file, not a robot.
SERIAL_SHIFT = 0.05     # share of the robot's length a URDF joint origin may move
SERIAL_TURN = 0.1       # rad a URDF joint origin or the instrument frame may turn
SERIAL_ANGLE = 0.35     # rad a robot file's alpha, beta, theta may move
SERIAL_ZERO = 0.5       # rad (m: SERIAL_SHIFT) a URDF joint's zero may move
# The calibrated model must explain the readings: the residual RMS of a length
# channel at most this share of the robot's size, of an angle channel this many rad.
EXPLAIN_LENGTH = 0.05
EXPLAIN_ANGLE = 0.02
LENGTH_CHANNELS = ("x", "y", "z", "marker", "distance")
ANGLE_CHANNELS = ("roll", "pitch", "yaw", "phi")


def robot_size(model) -> float:
    """How far the tool moves over the fit's poses at the start values (RMS distance
    of its origin from their mean, at least 0.1 m): the scale a calibration's lengths
    and residuals are judged against."""
    robot = model.robot
    try:
        T = robot.frames(model.qm, np.asarray(model.x0, dtype=float)[:robot.n_params])
    except Exception:  # noqa: BLE001 - a model without frames has no size to judge by
        return 1.0
    p = T[:, :3, 3]
    return max(float(np.sqrt(np.mean(np.sum((p - p.mean(axis=0)) ** 2, axis=1)))), 0.1)


def robot_reach(model) -> float:
    """The robot's own length at its start values: the sum of its chain's translations
    (joint origins, links, the tool), the instrument frame left out (at least 0.1 m)."""
    robot = model.robot
    chain = getattr(robot, "chain", None)
    if chain is None:
        return 1.0
    xi = np.asarray(model.x0, dtype=float)[:robot.n_params]
    names = robot.param_names
    total = 0.0
    for f in chain.factors:
        if f.kind[0] != "t" or f.joint is not None:
            continue
        if any(names[i].startswith("base_") for i, _c in f.terms):
            continue
        total += abs(f.const + sum(c * xi[i] for i, c in f.terms))
    return max(total, 0.1)


def _plausible_serial(quality, model, result) -> None:
    """A robot file's or URDF robot's calibration within what a real robot departs from
    its description: ratios within a factor :data:`PLAUSIBLE_FACTOR` and of the same
    sign, a robot file's lengths too (or, from 0, within :data:`SERIAL_SHIFT` of the
    robot's length, :func:`robot_reach`), its angles within :data:`SERIAL_ANGLE`; a URDF
    robot's joint origins within :data:`SERIAL_SHIFT` of its length and
    :data:`SERIAL_TURN`, its zeros within
    :data:`SERIAL_ZERO`, the instrument frame's correction within :data:`SERIAL_TURN`."""
    robot = model.robot
    size = robot_reach(model)
    urdf = hasattr(robot, "calibrated_origins")
    bad = []
    for j, (name, st) in enumerate(zip(result.names, result.status)):
        if not st.identifiable or name not in robot.param_names:
            continue
        x0, x = float(model.x0[j]), float(result.x[j])
        if not math.isfinite(x):
            bad.append((name, x0, x, "is not finite"))
            continue
        d = x - x0
        if name.startswith("k"):
            if x0 and not 1 / PLAUSIBLE_FACTOR <= x / x0 <= PLAUSIBLE_FACTOR:
                bad.append((name, x0, x, f"{x / x0:.3g} times the start"))
        elif urdf and name.startswith("j") and name.endswith(("_x", "_y", "_z")):
            if abs(d) > SERIAL_SHIFT * size:
                bad.append((name, x0, x, f"{d * 1e3:.4g} mm, beyond {SERIAL_SHIFT:.0%} of the "
                                         f"robot's length {size:.3g} m"))
        elif urdf and (name.startswith("j") or name.startswith("base_r")):
            if abs(d) > SERIAL_TURN:
                bad.append((name, x0, x, f"turned {math.degrees(d):.3g} deg"))
        elif name.endswith("_off"):
            i = int(name[1:-4])
            kind = robot.spec.joints[i - 1].kind
            # a robot file's prismatic zero is wherever its rail's encoder counts from
            lim = (SERIAL_ZERO if kind == "R" else SERIAL_SHIFT * size if urdf else math.inf)
            if abs(d) > lim:
                bad.append((name, x0, x, "a zero far from the URDF's (a joint map's offset or "
                                         "sign?)" if urdf else "a zero far from the robot "
                                         "file's (a joint column's offset or sign?)"))
        elif not urdf and name[0] in "da" and name[1:].isdigit():
            if (abs(x0) > 1e-3 and not 1 / PLAUSIBLE_FACTOR <= x / x0 <= PLAUSIBLE_FACTOR) \
                    or (abs(x0) <= 1e-3 and abs(d) > SERIAL_SHIFT * size):
                bad.append((name, x0, x, f"{d * 1e3:.4g} mm from the robot file's"))
        elif not urdf and name.startswith(("alpha", "beta", "theta")):
            if abs(d) > SERIAL_ANGLE:
                bad.append((name, x0, x, f"turned {math.degrees(d):.3g} deg"))
    if bad:
        quality.check("plausible", False, "plausible: " + ", ".join(
            f"{n} went from {a:.4g} to {b:.4g} ({why})" for n, a, b, why in bad)
            + "; a real robot departs from its description by less: a reading's unit, sign or "
            "frame, the joint values' units, zeros or order, or the robot file or URDF itself "
            "is likely wrong", parameters=[{"name": n, "start": a, "calibrated": b}
                                        for n, a, b, _ in bad])
    else:
        quality.check("plausible", True, "plausible: every correction within what a real "
                      "robot departs from its description")


def _explains(quality, model, result) -> None:
    """The calibrated model explains the readings: a length channel's residual RMS at
    most :data:`EXPLAIN_LENGTH` of the robot's size, an angle channel's at most
    :data:`EXPLAIN_ANGLE` rad. Without a stated noise the rest of the gate cannot tell
    a model that fits from one that does not (a unit, a mirrored axis, a wrong joint)."""
    size = robot_size(model)
    bad = []
    for ch, rms in (result.residual_rms or {}).items():
        if not math.isfinite(rms):
            bad.append(f"{ch} not finite")
        elif ch in LENGTH_CHANNELS and rms > EXPLAIN_LENGTH * size:
            bad.append(f"{ch} {rms * 1e3:.4g} mm ({rms / size:.0%} of the robot's size "
                       f"{size:.3g} m)")
        elif ch in ANGLE_CHANNELS and rms > EXPLAIN_ANGLE:
            bad.append(f"{ch} {math.degrees(rms):.3g} deg")
    if bad:
        quality.check("explains", False, "explains: the calibrated model leaves residual RMS "
                      + ", ".join(bad) + ": it does not explain the readings (a unit, e.g. "
                      "degrees read as radians or mm as m, a mirrored or swapped axis, a wrong "
                      "joint column or robot file)")
