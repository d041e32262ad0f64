"""The report's sections as data for its template (:mod:`station.outputs.report`): the
summary, the headline, the notes, the quality gate, the parameter table, the residuals per
channel, the held-out validation, the pose design, the events and each plan."""
from __future__ import annotations

import json

import numpy as np

from station.outputs import report_figures as figs
from station.outputs.fit_summary import describe_not_identified
from station.outputs.report_context import (IDENT_GROUPS, IDENT_SYMBOL, ReportContext, _finite,
                                            number_text, short)
from station.outputs.units import MM_DEG, param_units


def quality_view(outcome) -> dict | None:
    """The fit-quality gate (station.fitting.gate): verdict, outliers left out, each check."""
    q = getattr(outcome, "quality", None)
    if q is None:
        return None
    verdict = "passed" if q.passed else (
        "FAILED, accepted by the operator (--accept-poor-fit)" if q.accepted else "FAILED")
    return {"ok": q.passed, "verdict": verdict,
            "checks": [(c["ok"], c["message"]) for c in q.checks],
            "outliers": [(o["pose"], o["channel"], f"{o['residual']:.4g}", f"{o['t']:.3g}",
                          f"{o['threshold']:.3g}") for o in q.outliers]}


# -- sections ----------------------------------------------------------------------
def summary_view(ctx: ReportContext, validation: list) -> list[dict]:
    """Rows ``{"label", "text", "badge": (ok, text) or None, "lines": [...]}``."""
    res, model, trace = ctx.res, ctx.model, ctx.trace
    from calibration.methods import METHODS

    def row(label, text="", badge=None, lines=()):
        return {"label": label, "text": short(text), "badge": badge, "lines": list(lines)}

    mi = METHODS.get(ctx.method)
    method = ctx.method + (f" (report section {mi.section})" if mi and mi.section else "")
    residual_form = getattr(model, "residual", None)
    if residual_form:
        method += (", residual D_M - D (plain)" if residual_form == "plain"
                   else ", residual D_M\u00b2 - D\u00b2 (squared, report eqs. 63, 83)")
    n_poses = int(model.n_poses)
    enough = n_poses >= ctx.min_poses
    rows = [
        row("Robot", ctx.robot),
        row("Method", method),
        row("Trace", ctx.trace_name or "(not from a file)"),
        row("Trace SHA-256", ctx.trace_sha256()
            + (" (as in the parameter file)" if (ctx.outcome.document or {}).get("source_trace")
               else "")),
        row("Trace recorded", trace.header.get("created", "\u2013")),
        row("Report created", ctx.created),
        row("Poses", f"{n_poses} poses, {int(res.n_rows or len(ctx.after))} rows, "
                     f"p = {int(model.p)} (eq. 60)",
            (enough, f"eq. 60 minimum {ctx.min_poses} met" if enough
             else f"below the eq. 60 minimum of {ctx.min_poses}")),
        row("Eq. 60 minimum poses", f"m \u2265 5 N_R / p = 5 \u00b7 {res.n_identifiable} / "
                                    f"{int(model.p)} \u2192 {ctx.min_poses}"),
        row("Identifiable parameters", f"N_R = {res.n_identifiable} of {len(ctx.names)}"),
        row("Converged", res.message.removeprefix("converged "),
            (bool(res.converged), "converged" if res.converged else "NOT converged")),
        row("Iterations", f"{int(res.iterations)} ({int(res.nfev)} model evaluations, "
                          f"{res.wall_time:.3g} s)"),
        row("Condition number", f"{number_text(res.condition_number, '.4g')} (scaled, weighted "
                                "observation matrix at the solution)"),
        row("Sigma", "known: from the trace, used as the weights" if res.sigma_known else
            "estimated per channel at the solution (eq. 51)"),
    ]
    headline = validation_headline(validation, ctx.display)
    if headline:
        ok = all(_finite(v.get("rms_after")) and _finite(v.get("rms_before"))
                 and float(v["rms_after"]) < float(v["rms_before"]) for v in validation)
        rows.insert(6, row("Validation", headline,
                           (ok, "better on held-out poses" if ok
                            else "not better on every channel"
                            if all(_finite(v.get("rms_before")) for v in validation)
                            else "no before values")))
    cmp = ctx.outcome.comparison
    if cmp is not None:      # rigid against compliant (station.fitting.compliance)
        def figures(k, f):
            held = "-" if f["held_out_rms"] is None else f"{f['held_out_rms'] * 1e3:.4g} mm"
            return (f"{k}: {f['identifiable']} identifiable, fit RMS "
                    f"{f['fit_rms'] * 1e3:.4g} mm, held-out {held}")

        written = "compliant" if cmp.get("supported") else "rigid"
        rows.append(row("Model", f"rigid against compliant: the {written} model written",
                        (True, f"written: the {written} model"), lines=[cmp["statement"]] + [
                            figures(k, cmp[k]) for k in ("rigid", "compliant") if cmp.get(k)]))
    if getattr(trace, "truncated_tail", False):
        rows.append(row("Trace warning",
                        "the last line was truncated (recording interrupted) and skipped"))
    station = trace.header.get("station")
    if station:
        rows.append(row("Trace station record", station))
    doc = ctx.outcome.document
    if doc and doc.get("checksum"):
        rows.append(row("Parameter file", f"written {doc.get('created', '')}, {doc['checksum']}"))
    from station.outputs.fit_summary import frame_statement

    try:
        frame = frame_statement(trace)
    except Exception:  # noqa: BLE001
        frame = None
    if frame:
        qm = ", ".join(number_text(v) for v in frame["origin_qm"])
        rows.append(row("Base frame", frame["statement"] + ".",
                        lines=[f"origin_qm = [{qm}] (actuator units)"]))
    return rows


def headline(ctx: "ReportContext", validation: list) -> str:
    """One line at the top: how accurate the robot is now, on poses never fitted (the
    held-out validation), else in the fit's residuals."""
    u = ctx.display
    parts = []
    for v in validation:
        pts = v.get("points")
        if pts and _finite(pts.get("rms_after")):
            parts.append(f"the tool's points within {u.text(pts['rms_after'], 'm', '.3g')} RMS "
                         f"(max {u.text(pts.get('max_after'), 'm', '.3g')})")
        elif _finite(v.get("rms_after")):
            si = str(v.get("unit") or "")
            text = f"{v.get('channel')} {u.text(v['rms_after'], si, '.3g')} RMS"
            if _finite(v.get("rms_before")):
                text += f" ({u.text(v['rms_before'], si, '.3g')} before calibration)"
            parts.append(text)
    if parts:
        n = max((int(v.get("n") or 0) for v in validation), default=0)
        return ("After calibration the robot reads within " + "; ".join(parts)
                + f" on {n} held-out poses never used in the fit.")
    rms = {k: v for k, v in ctx.res.residual_rms.items() if _finite(v)}
    if not rms:
        return ""
    return ("After calibration the fit's residuals are " + "; ".join(
        f"{k} {u.text(v, ctx.channel_unit.get(k, ''), '.3g')} RMS" for k, v in rms.items())
        + " (no held-out poses: not checked on poses outside the fit).")


def validation_headline(validation, units=MM_DEG) -> str:
    """One line: per channel the held-out RMS before -> after with its unit and count
    (the reason where there is no "before")."""
    rows = list(validation or ())
    notes = {v.get("note") for v in rows}
    if rows and not any(_finite(v.get("rms_before")) for v in rows) and len(notes) == 1:
        # no "before" anywhere, for one reason: said once
        after = "; ".join(f"{v.get('channel')} "
                          f"{units.text(v.get('rms_after'), str(v.get('unit') or ''))}"
                          for v in rows)
        n = rows[0].get("n")
        reason = f" ({notes.pop()})" if None not in notes else ""
        return (f"RMS before calibration n/a{reason}; after: {after} over {n} held-out "
                "poses")
    parts = []
    for v in rows:
        si = str(v.get("unit") or "")
        pts = v.get("points")
        if pts:   # points on the tool: their 3D errors, as engineers read them
            parts.append(f"points' 3D RMS {units.text(pts.get('rms_before'), 'm')} \u2192 "
                         f"{units.text(pts.get('rms_after'), 'm')} (max "
                         f"{units.text(pts.get('max_after'), 'm')}) over {pts.get('n')} "
                         f"held-out points of {pts.get('poses')} poses")
            continue
        after = units.text(v.get("rms_after"), si)
        if _finite(v.get("rms_before")):
            before = units.text(v["rms_before"], si)
        else:
            before = "n/a" + (f" ({v['note']})" if v.get("note") else "")
        parts.append(f"{v.get('channel')} RMS {before} \u2192 {after} over {v.get('n')} "
                     "held-out poses")
    return "; ".join(parts)


def notes(ctx: ReportContext) -> list[str]:
    model, res = ctx.model, ctx.res
    notes = []
    op = getattr(model, "operator_notes", None)
    try:
        notes += list(op(ctx.x)) if callable(op) else list(getattr(model, "notes", ()) or ())
    except Exception:  # noqa: BLE001
        notes += list(getattr(model, "notes", ()) or ())
    for d in (ctx.outcome.document or {}).get("not_identified") or ():
        notes.append(describe_not_identified(d))
    doc_notes = (ctx.outcome.document or {}).get("notes") or ()
    base = set(getattr(model, "notes", ()) or ())
    notes += [n for n in doc_notes if n not in base]
    if model.n_poses < ctx.min_poses:
        notes.append(f"only {model.n_poses} poses for {res.n_identifiable} identifiable "
                     f"parameters; eq. 60 recommends at least {ctx.min_poses}")
    from station.outputs.fit_summary import operator_notes

    notes += operator_notes(ctx.outcome)
    infl = [n for n, g in zip(ctx.names, ctx.groups) if g == "influence"]
    if infl:
        notes.append("not identifiable and influencing the model: " + ", ".join(infl)
                     + "; kept at their start values, on which the other calibrated values "
                       "depend")
    return list(dict.fromkeys(notes))


def param_view(ctx: ReportContext) -> dict:
    titles = {k: t.lower() for k, t, _ in IDENT_GROUPS}
    nom = ctx.given_nominal
    groups = []
    for key, label, expl in IDENT_GROUPS:
        idx = [j for j, g in enumerate(ctx.groups) if g == key]
        if not idx:
            continue
        rows = []
        for j in idx:
            name = ctx.names[j]
            si = ctx.units.get(name, "")
            f = ctx.display.unit(si)[1] if si else 1.0      # mm and degrees for people
            s0, x = ctx.start[j], ctx.x[j]
            std = ctx.std[j] if key == "identifiable" else float("nan")
            change = x - s0
            sig = abs(change) / std if _finite(std) and std > 0 else float("nan")
            inverse = (number_text(1.0 / (x * f), ".6g") if name[:1] == "k" and name[1:].isdigit()
                       and _finite(x) and x != 0 else None)
            s0, x, std, change = s0 * f, x * f, std * f, change * f
            rows.append({"name": name, "unit": ctx.display.label(si) if si else "",
                         "nominal": number_text(nom[j] * f) if nom is not None else None,
                         "start": number_text(s0), "calibrated": number_text(x), "inverse": inverse,
                         "std": number_text(std, ".3g"),
                         "change": number_text(change, "+.4g") if change else number_text(change),
                         "significance": number_text(sig, ".3g"), "label": label.lower()})
        groups.append({"key": key, "symbol": IDENT_SYMBOL[key], "label": label, "expl": expl,
                       "rows": rows})
    return {
        "method": ctx.method,
        "strip": [{"name": n, "group": g, "symbol": IDENT_SYMBOL[g], "title": titles[g]}
                  for n, g in zip(ctx.names, ctx.groups)],
        "legend": [(k, IDENT_SYMBOL[k], t.lower()) for k, t, _ in IDENT_GROUPS],
        "has_nominal": nom is not None,
        "groups": groups,
    }


def channel_view(ctx: ReportContext) -> dict:
    res, u = ctx.res, ctx.display
    given, est = ctx.sigma_given(), ctx.sigma_estimated()
    rows = []
    for c, ch in enumerate(ctx.channels):
        si = ctx.channel_unit[ch]
        sel = ctx.rows_of(c)
        a = ctx.after[sel]
        b = ctx.before[sel] if ctx.before is not None else None
        rms_b = float(np.sqrt(np.mean(b ** 2))) if b is not None and b.size else None
        rms_a = float(np.sqrt(np.mean(a ** 2))) if a.size else None
        mx_a = float(np.max(np.abs(a))) if a.size else None
        rows.append({"channel": ch, "unit": u.label(si), "rows": int(sel.sum()),
                     "cells": [u.number(x, si) for x in (given.get(ch), est.get(ch),
                                                          res.sigma.get(ch), rms_b, rms_a,
                                                          mx_a)]})
    return {"rows": rows, "sigma_known": bool(res.sigma_known),
            "before_error": ctx.before_error}


def validation_view(rows: list, units) -> dict:
    out = []
    for v in rows:
        si = str(v.get("unit") or "")
        rb, ra = v.get("rms_before"), v.get("rms_after")
        change = (f"{(float(ra) / float(rb) - 1) * 100:+.4g} %"
                  if _finite(rb) and _finite(ra) and float(rb) != 0 else "\u2013")
        out.append({"channel": short(v.get("channel")), "unit": units.label(si),
                    "n": short(v.get("n")),
                    "cells": [units.number(v.get(k), si) for k in ("rms_before", "rms_after")]
                    + [change]
                    + [units.number(v.get(k), si) for k in ("max_before", "max_after")],
                    "note": short(v.get("note") or v.get("error") or "")})
    return {"rows": out, "figure": figs.fig_validation(rows, units),
            "headline": validation_headline(rows, units)}


def design_view(ctx: ReportContext, evs, val_rows, units) -> dict | None:
    """Predicted (the last plan's pose design, before measuring) and achieved (the
    calibration's std; the held-out validation) side by side, or None without a design."""
    design = None
    for ev in evs:
        if isinstance(ev, dict) and ev.get("kind") == "plan":
            rec = ev.get("design") or (ev.get("wrist") or {}).get("design")
            if isinstance(rec, dict):
                design = rec
    if design is None:
        return None
    res = ctx.outcome.result
    pred = design.get("predicted_std") or {}
    pu = param_units(ctx.outcome.trace)
    rows = []
    for j, (name, st) in enumerate(zip(res.names, res.status)):
        p = pred.get(name)
        if p is None or not st.identifiable:
            continue
        a = float(res.std[j])
        si = pu.get(name, "")
        f = units.unit(si)[1] if si else 1.0
        rows.append({"name": name, "unit": units.label(si) if si else "1",
                     "predicted": number_text(p * f, ".3g"), "achieved": number_text(a * f, ".3g"),
                     "ratio": f"{a / p:.2f}" if _finite(p) and float(p) > 0 else "\u2013"})
    held = design.get("predicted_heldout") or {}
    line = ""
    if held.get("rms") is not None:
        line = (f"predicted held-out {held.get('what')} error of the tool: "
                f"{units.text(held['rms'], held.get('unit', ''), '.3g')} RMS")
        ach = [v for v in val_rows if _finite(v.get("rms_after"))]
        if ach:
            line += "; achieved on the held-out poses: " + ", ".join(
                f"{v.get('channel')} {units.text(v['rms_after'], str(v.get('unit') or ''), '.3g')}"
                for v in ach)
    return {"rows": rows, "heldout": line, "design": short(design.get("design")),
            "poses": short(design.get("poses")),
            "observability": ", ".join(f"{k} {float(v):.3g}" for k, v in
                                       (design.get("observability") or {}).items())}


def merge_events(recorded, given) -> list:
    """The trace's events and the given ones, each (t, kind, message) once, in time
    order where every event has a time stamp."""
    out, seen = [], set()
    for ev in list(recorded) + list(given):
        if not isinstance(ev, dict):
            ev = {"message": ev}
        key = json.dumps([ev.get("t"), ev.get("kind"), ev.get("message")], default=str)
        if key in seen:
            continue
        seen.add(key)
        out.append(ev)
    if all(isinstance(ev.get("t"), str) for ev in out):
        out.sort(key=lambda ev: ev["t"])
    return out


def events_view(evs, units, robot=None) -> dict:
    """The events table (plans by reference) and each plan's poses as its own table (their
    targets in ``units``, named as ``robot``'s model names them)."""
    rows, plans = [], []
    for ev in evs:
        kind = str(ev.get("kind", ""))
        extra = {k: v for k, v in ev.items()
                 if k not in ("t", "kind", "message", "record", "poses")}
        poses = ev.get("poses") if isinstance(ev.get("poses"), list) else None
        details = short(extra) if extra else ""
        if poses is not None:
            plans.append(plan_view(len(plans) + 1, ev, poses, units, robot))
            details = (details + "; " if details else "") + f"poses: plan {len(plans)} below"
        rows.append({"t": short(ev.get("t", "")), "kind": short(kind),
                     "message": short(ev.get("message", "")), "details": short(details),
                     "fault": kind.lower() in ("fault", "error", "abort")})
    return {"rows": rows, "plans": plans}


def plan_view(number: int, ev: dict, poses: list, units=None, robot=None) -> dict:
    from station.outputs.units import MM_DEG, target_coords

    units = units or MM_DEG
    names, sis = target_coords(robot) if robot is not None else ((), ())

    def target(values) -> str:
        values = list(values or ())
        if len(values) != len(sis):        # not the robot's coordinates: as recorded
            return ", ".join(number_text(v, ".4g") for v in values)
        return ", ".join(f"{n} {units.text(v, si, '.4g')}" for n, v, si in zip(names, values, sis))

    out = []
    for p in poses:
        if not isinstance(p, dict):
            continue
        out.append({"index": short(p.get("index")),
                    "qm": short(", ".join(number_text(v, ".5g") for v in p.get("qm") or ())),
                    "target": short(target(p.get("target"))),
                    "held_out": p.get("use") == "validation",
                    "round": "scout" if p.get("round") in (0, None)
                    else f"round {short(p.get('round'))}"})
    wrist = isinstance(ev.get("wrist"), dict)
    rounds = wrist or "box_scale" in ev
    text = ("scout: poses near home that fit the wrist's start model; round N: a wider box "
            "planned from the fit of the poses before it" if wrist else
            "scout: poses a small step from the reference; round N: planned from the fit of "
            "the poses before it, in a larger part of the box")
    return {"number": number, "t": short(ev.get("t", "")),
            "message": short(ev.get("message", "")), "poses": out,
            "rounds": rounds, "rounds_text": text,
            "replace": bool(ev.get("replace"))}
