"""Batch calibration of a recorded trace: the one path of ``app.py batch``, the session
and the wizard.

Trace -> measurement model -> Algorithm 2 -> the fit-quality gate -> outcome (and, with
``out``, the parameter file: :func:`station.outputs.report.write_outputs`). No
parameter file is written unless the fit converged and passed the gate.
"""
from __future__ import annotations

import dataclasses
import math
import warnings

import numpy as np

from calibration.errors import CalibrationError
from calibration.methods import METHODS, build
from calibration.robots.base import canonical_result
from calibration.solver import SolverOptions, solve
from station.fitting.gate import gated_fit
from station.fitting.verdict import FitQualityError, NotConverged
from station.fitting.outcome import BatchOutcome
from station.fitting.start_values import ROUND_METHODS, staged_start, told_start
from station.outputs.report import write_outputs
from station.recording.channels import solver_sigma
from station.recording.trace import Trace, read_trace


class ConditioningWarning(UserWarning):
    """The model's form is ill-conditioned for this robot (e.g. DH on parallel axes)."""


def make_model(trace: Trace, *, method: str | None = None, residual: str | None = None):
    """The measurement model of a trace and its nominal vector."""
    method = method or trace.method
    mi = METHODS[method]
    robot = trace.robot_model()
    nominal = trace.nominal_vector(robot, trace.extra_params(method))
    if method == "sm-markers":
        nominal = registered_start(trace, robot, nominal)
    options = {}
    if residual:
        if method not in ("sm-distance", "sm-distance-tilt"):
            raise CalibrationError(f"--residual applies to the distance methods, not {method}")
        options["residual"] = residual
    if method == "sm-plane":
        given = all(k in (trace.header.get("nominal") or {}) for k in mi.extra_params)
        options["plane_given"] = given
    return build(method, robot, trace.method_data(method), nominal, **options), nominal


def registered_start(trace: Trace, robot, nominal: np.ndarray) -> np.ndarray:
    """sm-markers recorded at the station: the header knows the robot, not the instrument's
    frame nor the points on the tool (measured after the header was written); their
    start values are estimated from the fit poses as an import estimates them
    (:func:`station.recording.import_markers.start_values`: the reference-free start,
    with its checks). A trace whose header gives them (an import) keeps its own."""
    from calibration.methods.sm_markers import marker_names
    from station.recording.import_markers import pose_arrays, spread, start_values

    names = marker_names(trace.n_markers)
    if all(n in (trace.header.get("nominal") or {}) for n in names):
        return nominal
    start = start_values(robot, *pose_arrays(spread(trace.fit_poses)), str(trace.path))
    out = np.array(nominal, dtype=float)
    for name, v in start.items():
        k = (robot.index(name) if name in robot.param_names
             else robot.n_params + names.index(name))
        out[k] = v
    return out


def calibrate_trace(trace_path: str, *, out: str | None = None, method: str | None = None,
                    residual: str | None = None, options: SolverOptions | None = None,
                    callback=None, accept_poor_fit: bool = False,
                    exclude: dict | None = None, compliance: dict | None = None,
                    distance_scale: tuple | None = None,
                    outliers: str = "exclude") -> BatchOutcome:
    """Read a trace file and :func:`calibrate` it; ``compliance`` (``{"payload": ...}``)
    offers a URDF robot's joint compliance and keeps it only where the data support it
    (:func:`station.fitting.compliance.compare`)."""
    trace = read_trace(trace_path, method_override=method)
    if distance_scale is not None:
        trace = with_distance_scale(trace, *distance_scale)
    if compliance is None:
        return calibrate(trace, out=out, method=method, residual=residual, options=options,
                         callback=callback, accept_poor_fit=accept_poor_fit, exclude=exclude,
                         outliers=outliers)
    from station.fitting.compliance import compare

    def one(tr):
        return calibrate(tr, method=method, residual=residual, options=options,
                         callback=callback, accept_poor_fit=accept_poor_fit, exclude=exclude,
                         outliers=outliers)

    chosen, info = compare(trace, one, payload=compliance.get("payload"))
    chosen = dataclasses.replace(chosen, comparison=info)
    if out:
        chosen = write_outputs(chosen, trace_path, out)
    return chosen


def hold_patterns(trace_path: str, text: str, method: str | None = None) -> tuple[str, ...]:
    """``--hold a*,b``: the trace's parameters these shell patterns name, and the robot's
    own fixed ones (a pattern that names nothing is an error)."""
    import fnmatch

    trace = read_trace(trace_path, method_override=method)
    robot = trace.robot_model()
    names = tuple(robot.param_names) + trace.extra_params(method)
    held = list(getattr(robot, "fixed", ()) or ())
    for pat in (p.strip() for p in text.split(",")):
        if not pat:
            continue
        hit = [n for n in names if fnmatch.fnmatchcase(n, pat)]
        if not hit:
            raise CalibrationError(f"--hold {pat}: no parameter of {robot.name} "
                                   f"({trace.method}) matches it")
        held += [n for n in hit if n not in held]
    return tuple(held)


def with_distance_scale(trace: Trace, value: float, std: float, source: str) -> Trace:
    """``trace`` whose draw-wire readings are multiplied by ``value`` (``std``: its
    uncertainty, ``source``: a certificate, a reference length), recorded in the header
    (``distance_scale``)."""
    if "distance" not in METHODS[trace.method].channels:
        raise CalibrationError(f"--distance-scale is for the draw-wire's methods, not "
                               f"{trace.method}")
    header = dict(trace.header, distance_scale={"value": float(value), "std": float(std),
                                                "source": source})
    return dataclasses.replace(trace, header=header)


def scale_uncertainty(outcome: BatchOutcome) -> BatchOutcome:
    """The draw-wire scale's std added to the calibrated parameters' covariance: the
    parameters' sensitivity to the scale at the solution, ``dx/ds = (W^T L W)^-1 W^T L
    dr/ds`` with ``dr/ds`` the distance rows' readings divided by the scale (each
    calibrated length moves with it; angles do not), times its variance."""
    s, u = outcome.trace.distance_scale
    model, res = outcome.model, outcome.result
    if not u or "distance" not in model.channels:
        return outcome
    from calibration.quality import row_weights

    r, W = model.evaluate(res.x)
    active = np.array([st.identifiable for st in res.status])
    k = model.channels.index("distance")
    rows = np.asarray(model.row_channel) == k
    data = outcome.trace.method_data(model.method)
    D = np.asarray(data.channels["distance"], dtype=float)
    if getattr(model, "residual", "plain") == "squared":
        drds = np.zeros(len(r))
        drds[rows] = 2 * D * D / s
    else:
        drds = np.zeros(len(r))
        drds[rows] = D / s
    w = row_weights(model.row_channel, model.channels, res.sigma)
    A = W[:, active] * np.sqrt(w)[:, None]
    dxds = np.linalg.lstsq(A, np.sqrt(w) * drds, rcond=None)[0]
    cov = np.asarray(res.covariance, dtype=float) + u * u * np.outer(dxds, dxds)
    std = res.std.copy()
    std[active] = np.sqrt(np.clip(np.diag(cov), 0, None))
    return dataclasses.replace(outcome, result=dataclasses.replace(res, covariance=cov, std=std))


def exclude_poses(trace: Trace, exclude: dict) -> Trace:
    """``trace`` with the poses the operator excludes (``{index: reason}``) left out of
    the fit and of the held-out set; an index the trace does not hold is an error."""
    known = {p["index"] for p in trace.poses}
    missing = sorted(set(exclude) - known)
    if missing:
        raise CalibrationError(f"--exclude: the trace has no pose {missing[0]} (its poses are "
                               f"{min(known)}..{max(known)})")
    poses = [dict(p, use="excluded") if p["index"] in exclude else p for p in trace.poses]
    return dataclasses.replace(trace, poses=poses)


def _holding(opts: SolverOptions, hold) -> SolverOptions:
    """``opts`` also holding ``hold`` (names) at their start values."""
    extra = tuple(n for n in hold if n not in opts.fixed)
    return dataclasses.replace(opts, fixed=tuple(opts.fixed) + extra) if extra else opts


def _refit(trace, method, residual, opts, hold, start):
    """A gate's refit from ``start`` holding ``hold`` besides ``opts.fixed``; what it holds
    only because the model cannot identify it is reported as not identifiable (with its
    column's influence), not as fixed."""
    model, result = _fit(trace, method, residual, _holding(opts, hold), None, start=start)
    own = set(opts.fixed)
    status = tuple(dataclasses.replace(st, fixed=False) if st.fixed and st.name not in own
                   else st for st in result.status)
    return model, dataclasses.replace(result, status=status)


def _fit(trace: Trace, method, residual, opts, callback, model=None, start=None):
    """Algorithm 2 on ``trace`` (or ``model``), from ``start`` if given (a refit
    without outliers); the model keeps its own start values as the nominal."""
    if model is None:
        model, _ = make_model(trace, method=method, residual=residual)
    if start is not None and np.all(np.isfinite(start)):
        nominal = model.x0
        model.x0 = np.asarray(start, dtype=float).copy()
        try:
            result = solve(model, opts, callback=callback)
        finally:
            model.x0 = nominal
    else:
        result = solve(model, opts, callback=callback)
    # a robot file's arm keeps its first fit where it converged at the noise: there the
    # grown start moves parameters the data do not identify but that influence the
    # model (UR5-like sm-distance: 0.3-0.5 sigma the model then cannot explain)
    always = start is None and model.robot.name == "agebot-sm"
    if model.method in ROUND_METHODS and (always or not result.converged
                                          or _far_above_noise(result, opts.sigma)):
        # a far-off arm from the nominal: no convergence, or a local minimum whose
        # residuals are far above the sensors' noise (a drawn arm's 42 poses: 230
        # iterations to a cost 5e7 times the one at the truth). A session's trace
        # states no noise to tell, so the first fit always tries the start grown with
        # the data too and keeps the one that explains the readings better (3 of ten
        # drawn arms' sessions ended 1-14 cm RMS from their readings from the nominal)
        staged = _from_staged_start(trace, model, opts, callback)
        if staged is not None and (not result.converged or _explains_better(model, staged,
                                                                             result)):
            result = staged
    # angles written wrapped to (-pi, pi], the SM's a0 >= 0 (file-formats.md)
    result = canonical_result(model.robot, result, frame_free=model.method in ROUND_METHODS)
    if not result.converged:
        infl = [s.name for s in result.status if not s.identifiable and s.influences_model]
        hint = (f"; not identifiable and influencing the model: {', '.join(infl)} (their start "
                f"values must be right)" if infl else "")
        raise NotConverged(f"the calibration did not converge: {result.message}{hint}", model)
    return model, result


def calibrate(trace: Trace, *, out: str | None = None, method: str | None = None,
              residual: str | None = None, options: SolverOptions | None = None,
              callback=None, accept_poor_fit: bool = False,
              exclude: dict | None = None, outliers: str = "exclude") -> BatchOutcome:
    """Calibrate the fit poses of ``trace`` and pass the fit-quality gate
    (:mod:`station.fitting.gate`: outliers left out and refitted, noise, validation, pose
    spread); write the parameter file ``out`` if given. A failed gate raises
    :class:`station.fitting.verdict.FitQualityError` (nothing written) unless
    ``accept_poor_fit``. ``callback(k, iteration)`` is called after every
    iteration of the first fit (live plots). ``exclude``: poses the operator leaves out
    (``{index: reason}``), recorded in ``fit.quality.excluded``."""
    trace_path = trace.path
    if exclude:
        trace = exclude_poses(trace, exclude)
    model, _ = make_model(trace, method=method, residual=residual)
    opts = options or SolverOptions()
    fixed = tuple(getattr(model.robot, "fixed", ()) or ())
    if fixed and not opts.fixed:  # the robot file's fixed parameters
        opts = SolverOptions(**{**opts.__dict__, "fixed": fixed})
    for note in getattr(model, "notes", ()) or ():
        if "ill-conditioned" in note:
            warnings.warn(note, ConditioningWarning, stacklevel=2)
    stated = None
    if opts.sigma is None:
        stated = solver_sigma(model, trace)
        if stated:
            opts = SolverOptions(**{**opts.__dict__, "sigma": stated})
    else:
        stated = dict(opts.sigma)

    def validate(tr, mo, re):
        from station.fitting.validation import validation_errors

        return validation_errors(BatchOutcome(tr, mo, re, mo.x0, None))

    quality, trace, model, result, validation = gated_fit(
        trace, model, first=lambda: _fit(trace, method, residual, opts, callback, model),
        refit=lambda tr, start, hold=(): _refit(tr, method, residual, opts, hold, start),
        stated_sigma=stated,
        validate=validate, fixed=opts.fixed, outlier_mode=outliers)
    if exclude:
        quality.excluded = [{"pose": int(k), "reason": str(v)} for k, v in sorted(exclude.items())]
    if trace.remeasured:
        chains = [[p["index"] for p in trace.readings_of(p["index"])]
                  for p in trace.current_poses if p["index"] in set(trace.remeasured.values())]
        quality.check("remeasured", True, "measured again at the robot (a flagged reading; the "
                      "newest is used): " + ", ".join(" -> ".join(f"pose {i}" for i in c)
                                                      for c in chains), readings=chains)
    outcome = scale_uncertainty(BatchOutcome(trace, model, result, model.x0, None, quality,
                                             validation))
    if quality.passed:      # what each robot parameter buys the unseen poses (stated)
        from station.fitting.selection import judge as judge_selection, statement

        sel = judge_selection(outcome.model, outcome.result)
        if sel is not None:
            quality.check("selection", True, statement(sel), selection=sel)
    if not quality.passed:
        if not accept_poor_fit:
            raise FitQualityError(f"the fit failed the quality gate: {quality.summary()} "
                                  f"(no parameter file written; --accept-poor-fit to keep it "
                                  f"anyway)", outcome)
        quality.accepted = True
    if out:
        outcome = write_outputs(outcome, trace_path, out)
    return outcome


#: a converged fit whose estimated sigma of a channel is this many times the stated
#: one is taken for a local minimum (the residuals are not the sensors' noise)
FAR_ABOVE_NOISE = 30.0


def _far_above_noise(result, stated) -> bool:
    """Does some channel's residual RMS exceed its stated sigma :data:`FAR_ABOVE_NOISE`
    times (no stated sigma: False)? (Not the fit's sigma: with the noise stated, the
    solver's sigma is the stated one, whatever the residual.)"""
    for ch, s in (stated or {}).items():
        rms = (result.residual_rms or {}).get(ch)
        if s and rms is not None and math.isfinite(rms) and rms > FAR_ABOVE_NOISE * s:
            return True
    return False


def _explains_better(model, a, b) -> bool:
    """Does result ``a`` leave smaller residuals than ``b``? Each fit's cost is weighted
    by its own (estimated) sigma, so the two are compared with common weights: per
    channel, the smaller of the two residual RMS."""
    ca = cb = 0.0
    for k, ch in enumerate(model.channels):
        ra, rb = a.residual_rms.get(ch), b.residual_rms.get(ch)
        if ra is None or rb is None:
            continue
        w = max(min(ra, rb), np.finfo(float).tiny)
        n = int(np.sum(model.row_channel == k))
        ca += n * (ra / w) ** 2
        cb += n * (rb / w) ** 2
    return ca < cb


def _from_staged_start(trace: Trace, model, opts, callback):
    """The fit again from start values grown with the data
    (:func:`station.fitting.start_values.staged_start`) from the start values told what the
    reference showed (:func:`station.fitting.start_values.told_start`, as a session's rounds
    start); None where that does not converge either. The model's ``x0`` stays the
    trace's start values (validation's "before")."""
    data = trace.method_data(model.method)
    options = {"residual": getattr(model, "residual", "plain")}
    x = np.array(model.x0, dtype=float)
    ref = trace.reference
    if ref is not None and model.robot.name == "agebot-sm":
        n = model.robot.n_params
        x[:n] = told_start(model.method, model.robot, x[:n], ref["qm"], ref.get("tilt"))
    best = None
    # grown by quarters, and as the session grew it (its rounds' poses so far: what its
    # planning refits were fitted on); the one that explains the readings better. A
    # drawn arm's 36 poses (CI, seed 9422): by quarters, the 9-pose stage (the scout and
    # half of the middle round) went to a minimum 67 mm RMS from the readings, the gate
    # refused it; grown by rounds (12 poses) the fit reached 0.05 mm and 14 identifiable
    rounds = _round_cuts(trace)
    for cuts in (None,) if rounds is None else (None, rounds):
        start = staged_start(model.method, model.robot, data, x, options, cuts=cuts)
        if start is None:
            continue
        x0 = model.x0
        model.x0 = start
        try:
            res = solve(model, opts, callback=callback)
        finally:
            model.x0 = x0
        if res.converged and (best is None or _explains_better(model, res, best)):
            best = res
    return best


def _round_cuts(trace: Trace) -> list[int] | None:
    """How many fit poses (in recorded order) the trace held when each of its session's
    planning rounds but the last ended (the ``plan`` events' ``round`` of each pose);
    None where the trace has fewer than two rounds. Only where the round changes
    matters (a start, never the result): a round is a label here, whatever its type."""
    rounds = {}
    for ev in trace.events:
        if ev.get("kind") == "plan":
            for p in ev.get("poses", ()):
                if isinstance(p, dict) and "round" in p and "index" in p:
                    rounds[p["index"]] = p["round"]
    got = [rounds.get(p.get("plan_index")) for p in trace.fit_poses]
    if len(set(got) - {None}) < 2:
        return None
    return [k for k in range(1, len(got)) if got[k] != got[k - 1]]
