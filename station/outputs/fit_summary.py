"""A calibration's outcome for people and files: the parameter file's content
(:func:`outcome_document`; :func:`station.outputs.report.write_outputs` writes it with the
report), the parameter table ``app.py batch`` and ``run`` print (:func:`format_table`), and
what they say beyond the parameters (combinations, directions not identified, points on
the tool, the instrument's scale, the sm-distance-tilt base frame). The outcome is
:class:`station.fitting.outcome.BatchOutcome`, read by its fields."""
from __future__ import annotations

import math

import numpy as np

from calibration import identifiability as ident
from calibration.errors import CalibrationError
from station.outputs.params_file import params_document
from station.recording.trace import Trace, pose_name


def frame_statement(trace: Trace) -> dict | None:
    if (trace.method != "sm-distance-tilt" or trace.reference is None
            or "robot_file" in trace.header):  # a robot file's distances are from the point
        return None
    return {"origin_qm": trace.reference["qm"],
            "statement": ("theta0, a0 and q1_off refer to the base frame whose origin is the "
                          "end-effector position captured as the reference (origin_qm), with "
                          "axes parallel to the robot's base frame")}


def outcome_document(outcome, trace_path: str | None,
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


def not_identified(outcome) -> list[dict]:
    """Directions the method does not identify although every parameter is
    (``method.unidentified_directions``, e.g. pm-tilt's heading), each with the
    std the fit gives it; empty for most methods."""
    hook = getattr(outcome.model, "unidentified_directions", None)
    return hook(outcome.result) if callable(hook) and outcome.result.converged else []


def _fmt(v, width=13):
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "-".rjust(width)
    return f"{v:{width}.6g}"


def absorbed_names(outcome) -> dict[str, list[str]]:
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


def excluded_point_errors(outcome) -> dict | None:
    """The points' 3D errors of the calibrated model over every fit posture, those the
    gate excluded as outliers too (sm-markers; None without exclusions): ``{rms, poses,
    excluded: [{pose, where?, error}]}`` (m; each excluded pose's worst point)."""
    import dataclasses

    from calibration.methods import build

    model, res, trace = outcome.model, outcome.result, outcome.trace
    if not hasattr(model, "point_errors"):
        return None
    out_idx = {p["index"] for p in trace.current_poses if p.get("use") == "outlier"}
    if not out_idx:
        return None
    every = dataclasses.replace(trace, poses=[dict(p, use="fit") if p["index"] in out_idx
                                              else p for p in trace.poses])
    poses = every.fit_poses
    m = build(model.method, model.robot, every.method_data(model.method), res.x)
    e = m.point_errors(m.evaluate(res.x)[0])
    worst = {}
    for g, err in enumerate(e.tolist()):
        p = poses[int(m.pose_of[g])]
        if p["index"] in out_idx and err > worst.get(p["index"], (0.0, None))[0]:
            worst[p["index"]] = (err, p)
    excluded = [{"pose": i, "error": err, **({"where": p["source"]} if p.get("source") else {})}
                for i, (err, p) in sorted(worst.items())]
    return {"rms": float(np.sqrt(np.mean(e ** 2))), "poses": len(poses), "excluded": excluded}


def fit_point_errors(outcome) -> dict | None:
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
                       "point": int(model.marker_of[g]) + 1, "error": float(e[g]),
                       **({"where": poses[int(model.pose_of[g])]["source"]}
                          if poses[int(model.pose_of[g])].get("source") else {})}
                      for g in order]}


def operator_notes(outcome) -> list[str]:
    """What the operator must know beside the table, without ``note:``: the captured base
    origin (AGEBOT's arm, sm-distance-tilt) and the instrument's scale
    (:func:`scale_note`). The console, the wizard's Calibrate page and the report say
    the same."""
    out = []
    if outcome.trace.method == "sm-distance-tilt" and "robot_file" not in outcome.trace.header:
        out.append("theta0, a0 and q1_off refer to the captured base origin")
    return out + [n.removeprefix("note: ") for n in scale_note(outcome)]


def scale_note(outcome) -> list[str]:
    """What the instrument's scale means for the lengths: distance methods (the
    draw-wire's) and points measured in an instrument's frame (a tracker's, a motion
    capture's)."""
    if hasattr(outcome.model, "measured_points"):
        imported = "imported_from" in (outcome.trace.header.get("station") or {})
        return ["note: the instrument's scale is not observed: every calibrated length "
                "carries it (a 1 % scale error of the tracker or motion capture is 1 % of "
                "every length, with every check passed); its calibration certificate is the "
                "reference" + (" (units are checked at import)" if imported else "")]
    if "distance" not in getattr(outcome.model, "channels", ()):
        return []
    s, u = outcome.trace.distance_scale
    src = (outcome.trace.header.get("distance_scale") or {}).get("source")
    if src:
        return [f"note: the draw-wire's scale {s:.8g} +- {u:.2g} ({src}) is in every "
                "calibrated length and its std"]
    which = ("1 % of L2..L4 and k1" if outcome.trace.robot == "agebot-sm"
             else "1 % of every length")
    return ["note: distance and tilt do not observe the draw-wire's scale: the calibrated "
            f"lengths and ratios carry its error (1 % of scale, {which}); pin "
            "it with batch --distance-scale S,STD from its certificate or a known length"]


def format_table(outcome) -> str:
    """The parameter table (nominal, calibrated, std, identifiability) and fit figures."""
    res, model = outcome.result, outcome.model
    from station.outputs.units import MM_DEG, channel_si, param_units   # mm and degrees

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
                     f"({pose_name(w)} point {w['point']}); {pts['n']} points of "
                     f"{model.n_poses} poses")
        every = excluded_point_errors(outcome)
        if every:
            lines.append(f"fit over every posture, the excluded too: points' 3D RMS "
                         f"{every['rms'] * 1e3:.3g} mm over {every['poses']} poses; "
                         + ", ".join(f"{pose_name(x)} {x['error'] * 1e3:.3g} mm"
                                     for x in every["excluded"][:3])
                         + (f" and {len(every['excluded']) - 3} more"
                            if len(every["excluded"]) > 3 else "")
                         + " off the calibrated model")
    label = getattr(model.robot, "joint_label", None)
    if label is not None:
        lines.append("joints: " + ", ".join(f"{i} {label(i)}"
                                            for i in range(1, model.robot.n_actuators + 1)))
    for d in not_identified(outcome):
        lines.append(describe_not_identified(d))
    for note in getattr(model, "notes", ()) or ():
        lines.append(f"note: {note}")
    lines.extend(f"note: {n}" for n in operator_notes(outcome))
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
