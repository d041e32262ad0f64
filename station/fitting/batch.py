"""Headless batch calibration of a recorded trace (``app.py batch``).

Trace -> measurement model -> Algorithm 2 -> table and parameter file. No
parameter file is written unless the fit converged.
"""
from __future__ import annotations

import dataclasses
import math
import os
import warnings
from dataclasses import dataclass

import numpy as np

from calibration import identifiability as ident
from calibration.errors import CalibrationError
from calibration.methods import METHODS, build
from calibration.robots.base import canonical_result
from calibration.solver import CalibrationResult, SolverOptions, solve
from station.planning.arm_rounds import ROUND_METHODS, staged_start, told_start
from station.fitting.gate import FitQualityError, NotConverged, Quality, gated_fit
from station.outputs.params_file import checksum, params_document, write_params
from station.recording.trace import Trace, read_trace

# vector channels of a trace and the solver's row channels they map to
VECTOR_CHANNELS = {"pose": ("x", "y", "z", "phi"),
                   "position": ("x", "y", "z"),
                   "orientation": ("alpha", "beta", "gamma"),
                   "tilt": ("roll", "pitch")}
# the same for a robot file's 6-row pose
SERIAL_POSE = ("x", "y", "z", "roll", "pitch", "yaw")


class ConditioningWarning(UserWarning):
    """The model's form is ill-conditioned for this robot (e.g. DH on parallel axes)."""


@dataclass(frozen=True)
class BatchOutcome:
    trace: Trace
    model: object
    result: CalibrationResult
    nominal: np.ndarray
    document: dict | None
    quality: Quality | None = None
    validation: list | None = None
    comparison: dict | None = None   # rigid against compliant (station.fitting.compliance)


def solver_sigma(model, trace: Trace) -> dict | None:
    """The trace's ``sigma`` (per reading) as sigma per solver row channel,
    where the residual is a reading minus a prediction."""
    sig = trace.header.get("sigma") or {}
    comps = trace.header.get("components")
    out = {}
    for key, v in sig.items():
        if key == "distance" and getattr(model, "residual", "plain") == "squared":
            continue  # D^2 residual: its noise 2 D sigma differs per pose; estimate instead
        if key in model.channels and not isinstance(v, list):
            out[key] = float(v)
        elif key in VECTOR_CHANNELS:
            names = tuple(comps) if key == "orientation" and comps else VECTOR_CHANNELS[key]
            if key == "pose" and "roll" in model.channels:
                names = SERIAL_POSE
            vals = v if isinstance(v, list) else [v] * len(names)
            out.update({n: float(x) for n, x in zip(names, vals) if n in model.channels})
    return out or None


def make_model(trace: Trace, *, method: str | None = None, residual: str | None = None):
    """The measurement model of a trace and its nominal vector."""
    method = method or trace.method
    mi = METHODS[method]
    robot = trace.robot_model()
    nominal = trace.nominal_vector(robot, trace.extra_params(method))
    options = {}
    if residual:
        if method not in ("sm-distance", "sm-distance-tilt"):
            raise CalibrationError(f"--residual applies to the distance methods, not {method}")
        options["residual"] = residual
    if method == "sm-plane":
        given = all(k in (trace.header.get("nominal") or {}) for k in mi.extra_params)
        options["plane_given"] = given
    return build(method, robot, trace.method_data(method), nominal, **options), nominal


def frame_statement(trace: Trace) -> dict | None:
    if (trace.method != "sm-distance-tilt" or trace.reference is None
            or "robot_file" in trace.header):  # a robot file's distances are from the point
        return None
    return {"origin_qm": trace.reference["qm"],
            "statement": ("theta0, a0 and q1_off refer to the base frame whose origin is the "
                          "end-effector position captured as the reference (origin_qm), with "
                          "axes parallel to the robot's base frame")}


def calibrate_trace(trace_path: str, *, out: str | None = None, method: str | None = None,
                    residual: str | None = None, options: SolverOptions | None = None,
                    callback=None, accept_poor_fit: bool = False,
                    exclude: dict | None = None, compliance: dict | None = None,
                    distance_scale: tuple | None = None) -> BatchOutcome:
    """Read a trace file and :func:`calibrate` it; ``compliance`` (``{"payload": ...}``)
    offers a URDF robot's joint compliance and keeps it only where the data support it
    (:func:`station.fitting.compliance.compare`)."""
    trace = read_trace(trace_path, method_override=method)
    if distance_scale is not None:
        trace = with_distance_scale(trace, *distance_scale)
    if compliance is None:
        return calibrate(trace, out=out, method=method, residual=residual, options=options,
                         callback=callback, accept_poor_fit=accept_poor_fit, exclude=exclude)
    from station.fitting.compliance import compare

    def one(tr):
        return calibrate(tr, method=method, residual=residual, options=options,
                         callback=callback, accept_poor_fit=accept_poor_fit, exclude=exclude)

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
              exclude: dict | None = None) -> BatchOutcome:
    """Calibrate the fit poses of ``trace`` and pass the fit-quality gate
    (:mod:`station.fitting.gate`: outliers left out and refitted, noise, validation, pose
    spread); write the parameter file ``out`` if given. A failed gate raises
    :class:`station.fitting.gate.FitQualityError` (nothing written) unless
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
        validate=validate, fixed=opts.fixed)
    if exclude:
        quality.excluded = [{"pose": int(k), "reason": str(v)} for k, v in sorted(exclude.items())]
    outcome = scale_uncertainty(BatchOutcome(trace, model, result, model.x0, None, quality,
                                             validation))
    if not quality.passed:
        if not accept_poor_fit:
            raise FitQualityError(f"the fit failed the quality gate: {quality.summary()} "
                                  f"(no parameter file written; --accept-poor-fit to keep it "
                                  f"anyway)", outcome)
        quality.accepted = True
    if out:
        outcome = write_outputs(outcome, trace_path, out)
    return outcome


def write_outputs(outcome: BatchOutcome, trace_path: str | None, out, report=None,
                  **report_options) -> BatchOutcome:
    """Write the parameter file ``out`` and, if given, the HTML ``report``: both or
    neither (the report first; removed again if the parameter file cannot be
    written). Returns the outcome with its document."""
    doc = outcome_document(outcome, trace_path)
    doc["checksum"] = checksum(doc)
    outcome = dataclasses.replace(outcome, document=doc)
    if report:
        from station.outputs.report import write_report

        if "validation" not in report_options and outcome.validation:
            report_options = dict(report_options, validation=outcome.validation)
        write_report(report, outcome, **report_options)
    try:
        write_params(out, doc)
    except BaseException:
        if report:
            try:
                os.unlink(report)
            except OSError:
                pass
        raise
    return outcome


def outcome_document(outcome: BatchOutcome, trace_path: str | None,
                     notes: list[str] | None = None) -> dict:
    """The parameter file's content (no checksum) for a calibration outcome: batch,
    session and the GUI's offline page write the same fields, ``fit.quality``
    included. ``notes`` default to the model's and eq. 60's."""
    if notes is None:
        notes = list(getattr(outcome.model, "notes", ()) or ())
        res, model = outcome.result, outcome.model
        need = ident.minimum_poses(res.n_identifiable, model.p)
        if model.n_poses < need:
            notes.append(f"only {model.n_poses} poses for {res.n_identifiable} identifiable "
                         f"parameters; eq. 60 recommends at least {need}")
    quality = outcome.quality.as_dict() if outcome.quality is not None else None
    src = outcome.trace.header.get("robot_file")
    extra = {"robot_file": src} if src else {}
    robot = outcome.model.robot
    if hasattr(robot, "calibrated_origins"):
        from station.outputs.export_urdf import urdf_summary

        extra["urdf"] = urdf_summary(robot, outcome.result.x[:robot.n_params])
    if outcome.comparison is not None:
        extra["model_comparison"] = dict(outcome.comparison)
    if outcome.trace.header.get("distance_scale"):
        extra["distance_scale"] = dict(outcome.trace.header["distance_scale"])
    absorbs = absorbed_names(outcome)
    pts = fit_point_errors(outcome)
    if pts:
        n = robot.n_params
        u = outcome.result.x[n:].reshape(-1, 3)
        extra["points_on_tool"] = {
            f"point{j}": {"xyz": [float(v) for v in p], "frame": outcome.model.robot.spec.tip_link}
            for j, p in enumerate(u, start=1)}
        extra["fit_points"] = pts
    unseen = not_identified(outcome)
    if unseen:
        extra["not_identified"] = unseen
    doc = params_document(outcome.result, robot=outcome.trace.robot,
                          nominal=outcome.model.x0, trace_path=trace_path,
                          poses=outcome.model.n_poses, frame=frame_statement(outcome.trace),
                          notes=notes, quality=quality, extra=extra or None)
    for name, hs in absorbs.items():   # identifiable only with these held: a combination
        doc["parameters"][name]["absorbs"] = hs
    return doc


def describe_not_identified(d: dict) -> str:
    """One line for a ``not_identified`` entry (table, report, wizard)."""
    text = (f"not identified: {d['direction']} ({d['statement']}): std "
            f"{math.degrees(d['std_rad']):.3g} deg over +-{d.get('box_deg', 15):g} deg")
    if "ik_std" in d:
        text += (f", {d['ik_std']:.3g} actuator units of the IK; the IK without it "
                 f"{d['ik_std_modulo_heading']:.3g} units")
    return text


def not_identified(outcome: BatchOutcome) -> list[dict]:
    """Directions the method does not identify although every parameter is
    (``method.unidentified_directions``, e.g. pm-tilt's heading), each with the
    std the fit gives it; empty for most methods."""
    hook = getattr(outcome.model, "unidentified_directions", None)
    return hook(outcome.result) if callable(hook) and outcome.result.converged else []


#: a converged fit whose estimated sigma of a channel is this many times the stated
#: one is taken for a local minimum (the residuals are not the sensors' noise)
FAR_ABOVE_NOISE = 30.0


def _far_above_noise(result, stated) -> bool:
    """Does some channel's estimated sigma exceed its stated one :data:`FAR_ABOVE_NOISE`
    times (no stated sigma: False)?"""
    for ch, s in (stated or {}).items():
        est = (result.sigma or {}).get(ch)
        if s and est is not None and math.isfinite(est) and est > FAR_ABOVE_NOISE * s:
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
    (:func:`station.planning.arm_rounds.staged_start`) from the start values told what the
    reference showed (:func:`station.planning.arm_rounds.told_start`, as a session's rounds
    start); None where that does not converge either. The model's ``x0`` stays the
    trace's start values (validation's "before")."""
    data = trace.method_data(model.method)
    options = {"residual": getattr(model, "residual", "plain")}
    x = np.array(model.x0, dtype=float)
    ref = trace.reference
    if ref is not None and model.robot.name == "agebot-sm":
        n = model.robot.n_params
        x[:n] = told_start(model.method, model.robot, x[:n], ref["qm"], ref.get("tilt"))
    start = staged_start(model.method, model.robot, data, x, options)
    if start is None:
        return None
    x0 = model.x0
    model.x0 = start
    try:
        res = solve(model, opts, callback=callback)
    finally:
        model.x0 = x0
    return res if res.converged else None


def _fmt(v, width=13):
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "-".rjust(width)
    return f"{v:{width}.6g}"


def absorbed_names(outcome: BatchOutcome) -> dict[str, list[str]]:
    """Per identifiable parameter, the held parameters whose errors its value absorbs
    (:func:`calibration.identifiability.absorbed`, at the solution, weighted by the fit's
    sigma): its value and std are those of a combination."""
    res, model = outcome.result, outcome.model
    try:
        W = model.evaluate(res.x)[1]
    except CalibrationError:
        return {}
    from calibration.quality import row_weights

    w = row_weights(model.row_channel, model.channels, res.sigma)
    ident_mask = [s.identifiable for s in res.status]
    # the held ones the analysis found dependent (not the fixed: their columns may be
    # independent, and their error then biases rather than is absorbed)
    infl = [s.influences_model and not s.fixed for s in res.status]
    got = ident.absorbed(W, w, ident_mask, infl)
    return {res.names[j]: [res.names[h] for h in hs] for j, hs in got.items()}


def fit_point_errors(outcome: BatchOutcome) -> dict | None:
    """3D errors of the fit's points on the tool (sm-markers): RMS, max and the worst
    three by pose and point (m); None for other methods."""
    model, res = outcome.model, outcome.result
    if not hasattr(model, "point_errors"):
        return None
    e = model.point_errors(model.evaluate(res.x)[0])
    poses = outcome.trace.fit_poses
    order = np.argsort(-e)[:3]
    return {"n": int(e.size), "rms": float(np.sqrt(np.mean(e ** 2))), "max": float(e.max()),
            "worst": [{"pose": int(poses[int(model.pose_of[g])]["index"]),
                       "point": int(model.marker_of[g]) + 1, "error": float(e[g])}
                      for g in order]}


def scale_note(outcome: BatchOutcome) -> list[str]:
    """What the instrument's scale means for the lengths: distance methods (the
    draw-wire's) and points measured in an instrument's frame (a tracker's, a motion
    capture's)."""
    if hasattr(outcome.model, "measured_points"):
        return ["note: the instrument's scale is not observed: every calibrated length "
                "carries it (a 1 % scale error of the tracker or motion capture is 1 % of "
                "every length, with every check passed); its calibration certificate is the "
                "reference (units are checked at import)"]
    if "distance" not in getattr(outcome.model, "channels", ()):
        return []
    s, u = outcome.trace.distance_scale
    src = (outcome.trace.header.get("distance_scale") or {}).get("source")
    if src:
        return [f"note: the draw-wire's scale {s:.8g} +- {u:.2g} ({src}) is in every "
                "calibrated length and its std"]
    return ["note: distance and tilt do not observe the draw-wire's scale: the calibrated "
            "lengths and ratios carry its error (1 % of scale, 1 % of L2..L4 and k1); pin "
            "it with batch --distance-scale S,STD from its certificate or a known length"]


def format_table(outcome: BatchOutcome) -> str:
    """The parameter table (nominal, calibrated, std, identifiability) and fit figures."""
    res, model = outcome.result, outcome.model
    from station.outputs.report import param_units    # numbers for people: mm and degrees
    from station.outputs.units import MM_DEG, channel_si

    units, si = MM_DEG, param_units(outcome.trace)
    lines = [f"{'parameter':<10}{'unit':<6}{'start':>13}{'calibrated':>13}{'std':>13}"
             "  identifiability", "-" * 78]
    held = getattr(model.robot, "held_reason", lambda _n: "the robot file's fixed")
    absorbs = absorbed_names(outcome)
    width = max([10] + [len(n) + 1 for n in res.names])
    lines[0] = f"{'parameter':<{width}}" + lines[0][10:]
    for j, (name, st) in enumerate(zip(res.names, res.status)):
        std = res.std[j] if st.identifiable else None
        infl = "influences the model" if st.influences_model else "no influence"
        label = "identifiable" if st.identifiable else (
            f"held ({held(name)}), {infl}" if st.fixed else f"not identifiable, {infl}")
        if name in absorbs:
            hs = absorbs[name]
            label += ("; with " + ", ".join(hs[:4]) + (f" and {len(hs) - 4} more" if len(hs) > 4
                                                        else "") + " held: a combination")
        u = si.get(name, "")

        def shown(v, u=u):
            return None if v is None else units.value(v, u)
        lines.append(f"{name:<{width}}{units.label(u) or '1':<6}{_fmt(shown(outcome.nominal[j]))}"
                     f"{_fmt(shown(res.x[j]))}{_fmt(shown(std))}  {label}")
    need = ident.minimum_poses(res.n_identifiable, model.p)
    lines.append("-" * 78)
    lines.append(f"method {res.method}: {res.message}")
    lines.append(f"identifiable {res.n_identifiable} of {len(res.names)}; poses {model.n_poses} "
                 f"(eq. 60 recommends >= {need}); condition number {res.condition_number:.4g}")
    sig = ", ".join(f"{k} {units.text(v, channel_si(k))}" for k, v in res.sigma.items())
    rms = ", ".join(f"{k} {units.text(v, channel_si(k))}" for k, v in res.residual_rms.items())
    lines.append(f"sigma ({'from the trace' if res.sigma_known else 'estimated, eq. 51'}): {sig}")
    lines.append(f"residual RMS: {rms}")
    pts = fit_point_errors(outcome)
    if pts:
        w = pts["worst"][0]
        lines.append(f"fit: points' 3D RMS {pts['rms'] * 1e3:.3g} mm, max {pts['max'] * 1e3:.3g} mm "
                     f"(pose {w['pose']} point {w['point']}); {pts['n']} points of "
                     f"{model.n_poses} poses")
    label = getattr(model.robot, "joint_label", None)
    if label is not None:
        lines.append("joints: " + ", ".join(f"{i} {label(i)}"
                                            for i in range(1, model.robot.n_actuators + 1)))
    for d in not_identified(outcome):
        lines.append(describe_not_identified(d))
    for note in getattr(model, "notes", ()) or ():
        lines.append(f"note: {note}")
    if outcome.trace.method == "sm-distance-tilt" and "robot_file" not in outcome.trace.header:
        lines.append("note: theta0, a0 and q1_off refer to the captured base origin")
    lines.extend(scale_note(outcome))
    if any(si.get(n, "").endswith("/u") for n in res.names):
        lines.append("unit u: the actuator unit of qm (the drives' position unit: "
                     "[canopen] increments_per_unit of the station config)")
    if outcome.quality is not None:
        lines.extend(outcome.quality.lines())
    c = outcome.comparison
    if c is not None:
        for key in ("rigid", "compliant"):
            f = c.get(key)
            if f:
                held = f["held_out_rms"]
                lines.append(f"model {key:>9}: {f['identifiable']} identifiable, fit RMS "
                             f"{f['fit_rms'] * 1e3:.4g} mm, held-out "
                             f"{'-' if held is None else f'{held * 1e3:.4g} mm'}, gate {f['gate']}")
        lines.append(f"{c['statement']}; written: the "
                     f"{'compliant' if c.get('supported') else 'rigid'} model")
    return "\n".join(lines)
