"""The calibration report: one self-contained HTML file (``app.py batch --report``).

What a robotics engineer looks at after a calibration: the fit in one summary
(robot, method, trace and its SHA-256, poses against eq. 60, convergence, sigma
per channel, condition number, the held-out validation in one line, the
sm-distance-tilt base frame), the parameter table grouped by identifiability as
in the report's Table 3, the figures of the report's section 7 (parameter
convergence, variance and condition number per iteration), the residuals per
channel before and after calibration, and, when given, held-out validation, the
session's events (each plan as its own compact table) and the station setup.

This module gathers the numbers (:class:`_Context`, the ``_*_view`` functions);
the page itself is the Jinja2 template ``station/templates/report.html.j2``
(autoescaped: every text from a trace, a session or an event is escaped) and the
figures come from :mod:`station.outputs.report_figures`. Numbers for people are in the
display units of :mod:`station.outputs.units` (mm and degrees by default), parameters in
SI as in the parameter file. No table cell is longer than :data:`CELL_MAX`
characters. The file needs nothing else and opens offline; it is written
atomically (temporary file, fsync, rename), so a failure leaves no partial report.
"""
from __future__ import annotations

import copy
import json
import math
import os
from pathlib import Path

import numpy as np

from calibration import identifiability as ident
from calibration.errors import StationError
from drivers.atomic import check_writable, write_atomic
from station.outputs import report_figures as figs
from station.fitting.batch import describe_not_identified
from station.outputs.params_file import file_sha256
from station.recording.trace import utc_now
from station.outputs.units import MM_DEG, channel_si

IDENT_GROUPS = (
    ("identifiable", "Identifiable",
     "calibrated; the std is the square root of the covariance diagonal (eq. 52)"),
    ("no-influence", "Not identifiable, without influence",
     ("the measurements do not depend on it: kept at its start value, and a wrong start "
      "value does not bias the others")),
    ("influence", "Not identifiable, with influence",
     ("a combination of other columns: kept at its start value, and a wrong start value "
      "biases the others, so it must be known")),
    ("fixed", "Fixed",
     ("held at its given value (the robot file's fixed), not calibrated; where the "
      "measurements depend on it (\"influences the model\") a wrong value biases the others")),
)
# Table 3 symbols
IDENT_SYMBOL = {"identifiable": "\u2713", "no-influence": "\u25cb", "influence": "\u25cf",
                "fixed": "\u25a0"}

# units of the parameters (SI, as in the parameter file)
PARAM_UNITS = {
    "agebot-sm": {"q1_off": "m", "q2_off": "rad", "q3_off": "rad", "q4_off": "rad",
                  "k1": "m/u", "k2": "rad/u", "k3": "rad/u", "k4": "rad/u",
                  "L2": "m", "L3": "m", "L4": "m", "theta0": "rad", "a0": "m",
                  "plane_a": "1/m", "plane_b": "1/m", "plane_c": "1/m", "distance_off": "m"},
    "agebot-pm": {"a1": "m", "a2": "m", "l": "m", "v": "m",
                  "q1_off": "m", "q2_off": "m", "q3_off": "m",
                  "k1": "m/u", "k2": "m/u", "k3": "m/u", "mount_x": "rad", "mount_y": "rad"},
}
CELL_MAX = 300          # characters in one table cell at most


def param_units(trace) -> dict:
    """Units of a trace's parameters: the built-ins' table, or a robot file's by
    the spec's naming (lengths m, angles rad, a joint's offset and ratio by its type)."""
    model = trace.robot_model() if hasattr(trace, "robot_model") else None
    spec = getattr(model, "spec", None)
    if spec is None:
        return PARAM_UNITS.get(str(trace.header.get("robot", "")), {})
    out = {"mount_x": "rad", "mount_y": "rad", "distance_off": "m",
           "plane_a": "1/m", "plane_b": "1/m", "plane_c": "1/m"}
    for name in model.param_names:
        key = name.split("_")[-1].rstrip("0123456789")
        out[name] = "rad" if key in ("theta", "alpha", "beta", "gamma") else "m"
    for i, jt in enumerate(spec.joints, start=1):
        q = "rad" if jt.kind == "R" else "m"
        out[f"q{i}_off"], out[f"k{i}"] = q, f"{q}/u"
    return out
TEMPLATE = "report.html.j2"


class ReportError(StationError):
    """The report could not be made or written; nothing was left behind."""


# -- public ---------------------------------------------------------------------
def write_report(path, outcome, *, validation=None, events=(), title=None,
                 session=None, units=MM_DEG) -> Path:
    """Write the HTML report of a batch outcome (:class:`station.fitting.batch.BatchOutcome`)
    atomically to ``path`` and return the path.

    validation: held-out poses, a list of dicts ``{"channel", "unit", "n", "rms_before",
                "rms_after", "max_before", "max_after"}`` (SI with its unit; table,
                summary line and bar chart).
    events:     event records (dicts with ``t``, ``kind``, ``message``) shown with the
                trace's own events (exact repeats once).
    title:      the page title (default: robot, method and trace file).
    session:    free key/values (station config, devices, operator...), a small table.
    units:      :class:`station.outputs.units.Units` for the numbers people read.
    """
    path = Path(path)
    _check_writable(path)  # before the figures: fail fast
    text = render_report(outcome, validation=validation, events=events, title=title,
                         session=session, units=units)
    try:
        write_atomic(path, text.encode("utf-8"))
    except OSError as e:
        reason = e.strerror or str(e)
        raise ReportError(f"cannot write the report {path}: {reason}") from None
    return path


def _check_writable(path: Path) -> None:
    check_writable(path, "the report", error=ReportError)


def _quality_view(outcome) -> dict | None:
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


def template_environment():
    """The Jinja2 environment of the report templates (package data of ``station``)."""
    import jinja2

    return jinja2.Environment(
        loader=jinja2.PackageLoader("station", "templates"),
        autoescape=True, trim_blocks=True, lstrip_blocks=True,
        undefined=jinja2.StrictUndefined)


def render_report(outcome, *, validation=None, events=(), title=None, session=None,
                  units=MM_DEG) -> str:
    """The report's HTML text (see :func:`write_report`)."""
    try:
        from matplotlib.backends.backend_agg import FigureCanvasAgg  # noqa: F401
        import jinja2  # noqa: F401
    except ModuleNotFoundError as e:
        raise ReportError(f"the HTML report needs {e.name} (a dependency of this package): "
                          "pip install -e .") from None
    ctx = _Context(outcome, units)
    title = title or (f"Calibration report: {ctx.robot}, {ctx.method}"
                      + (f", {ctx.trace_name}" if ctx.trace_name else ""))
    val_rows = [dict(v) for v in validation or () if isinstance(v, dict)]
    evs = _merge_events(getattr(outcome.trace, "events", ()) or (), events or ())
    page = {
        "title": title,
        "headline": headline(ctx, val_rows),
        "created": ctx.created,
        "summary": _summary_view(ctx, val_rows),
        "notes": _notes(ctx),
        "quality": _quality_view(outcome),
        "params": _param_view(ctx),
        "channels": _channel_view(ctx),
        "figures": figs.figures(ctx),
        "history": bool(list(outcome.result.history)),
        "validation": _validation_view(val_rows, units) if val_rows else None,
        "design": _design_view(ctx, evs, val_rows, units),
        "events": _events_view(evs, units) if evs else None,
        "session": ([(str(k), short(v)) for k, v in session.items()]
                    if isinstance(session, dict) else [("session", short(session))])
        if session else None,
    }
    return template_environment().get_template(TEMPLATE).render(**page)


# -- data -----------------------------------------------------------------------
class _Context:
    """What the sections and figures share, computed once."""

    def __init__(self, outcome, display=MM_DEG):
        self.outcome = outcome
        self.display = display
        self.trace, self.model, self.res = outcome.trace, outcome.model, outcome.result
        res, model = self.res, self.model
        self.robot = str(self.trace.header.get("robot", ""))
        self.method = str(res.method or getattr(model, "method", ""))
        self.created = utc_now()
        self.names = tuple(res.names)
        self.start = np.asarray(outcome.nominal if outcome.nominal is not None else res.x0,
                                dtype=float)
        self.x = np.asarray(res.x, dtype=float)
        self.std = np.asarray(res.std, dtype=float)
        self.groups = [group_of(st) for st in res.status]
        nom = getattr(model, "nominal", None)
        try:
            nom = np.asarray(nom, dtype=float) if nom is not None else None
        except (TypeError, ValueError):
            nom = None
        # the nominal as given, where the method re-estimated start values from it
        self.given_nominal = (nom if nom is not None and nom.shape == self.start.shape
                              and not np.array_equal(nom, self.start)
                              else None)
        self.units = param_units(self.trace)
        self.trace_path = getattr(self.trace, "path", None)
        self.trace_name = os.path.basename(self.trace_path) if self.trace_path else ""
        self.channels = tuple(model.channels)
        self.row_channel = np.asarray(model.row_channel)
        squared = getattr(model, "residual", "plain") == "squared"
        self.channel_unit = {ch: ("m\u00b2" if ch == "distance" and squared
                                  else channel_si(ch)) for ch in self.channels}
        self.after = np.asarray(res.residual, dtype=float)
        self.before, self.before_error = self._before()
        self.n_active = res.n_identifiable
        self.min_poses = ident.minimum_poses(res.n_identifiable, model.p)

    def _before(self):
        """Residual at the start values, on a copy of the model (some models keep
        state between evaluations, e.g. the PM's assembly mode)."""
        try:
            try:
                model = copy.deepcopy(self.model)
            except Exception:  # noqa: BLE001 - a model that cannot be copied is used as is
                model = self.model
            r, _ = model.evaluate(np.array(self.start, dtype=float))
            r = np.asarray(r, dtype=float)
            if r.shape != self.after.shape:
                return None, f"the start residual has {r.size} rows, the final {self.after.size}"
            return r, None
        except Exception as e:  # noqa: BLE001 - shown in the report, not fatal
            return None, f"{e.__class__.__name__}: {e}"

    def rows_of(self, c: int) -> np.ndarray:
        return self.row_channel == c

    def trace_sha256(self) -> str:
        doc = self.outcome.document or {}
        src = doc.get("source_trace") or {}
        if src.get("sha256"):
            return str(src["sha256"])
        if self.trace_path:
            try:
                return file_sha256(self.trace_path)
            except OSError as e:
                return f"unavailable ({e.strerror or e})"
        return "unavailable"

    def sigma_given(self) -> dict:
        from station.fitting.batch import solver_sigma

        try:
            return solver_sigma(self.model, self.trace) or {}
        except Exception:  # noqa: BLE001 - informative only
            return {}

    def sigma_estimated(self) -> dict:
        """Eq. 51 per channel at the solution, with the channel's share of the
        degrees of freedom (as the solver does)."""
        n = max(len(self.after), 1)
        out = {}
        for c, ch in enumerate(self.channels):
            r = self.after[self.rows_of(c)]
            nc = r.size
            if nc == 0:
                continue
            dof = nc - self.n_active * nc / n
            rss = float(np.sum(r ** 2))
            out[ch] = math.sqrt(rss / dof) if dof > 0 else math.sqrt(rss / nc)
        return out


def group_of(st) -> str:
    """The parameter's group of :data:`IDENT_GROUPS` from its status."""
    if st.identifiable:
        return "identifiable"
    if getattr(st, "fixed", False):
        return "fixed"
    return "influence" if st.influences_model else "no-influence"


# -- formatting -------------------------------------------------------------------
_finite = figs.finite


def _num(v, fmt=".7g") -> str:
    if not _finite(v):
        return "\u2013"
    return format(float(v), fmt)


def short(v, limit: int = CELL_MAX) -> str:
    """A value as table text of at most ``limit`` characters: numbers formatted,
    mappings as ``key: value; ...``, lists comma-separated, the rest cut with an
    ellipsis."""
    if isinstance(v, bool):
        text = str(v)
    elif isinstance(v, (int, np.integer)):
        text = str(int(v))
    elif isinstance(v, (float, np.floating)):
        text = _num(v, ".4g")
    elif v is None:
        text = "\u2013"
    elif isinstance(v, dict):
        text = "; ".join(f"{k}: {short(x, limit)}" for k, x in v.items())
    elif isinstance(v, (list, tuple)):
        text = ", ".join(short(x, limit) for x in v)
    else:
        text = str(v)
    return text if len(text) <= limit else text[: limit - 1] + "\u2026"


# -- sections ----------------------------------------------------------------------
def _summary_view(ctx: _Context, validation: list) -> list[dict]:
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
        row("Condition number", f"{_num(res.condition_number, '.4g')} (scaled, weighted "
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
    if getattr(trace, "truncated_tail", False):
        rows.append(row("Trace warning",
                        "the last line was truncated (recording interrupted) and skipped"))
    station = trace.header.get("station")
    if station:
        rows.append(row("Trace station record", station))
    doc = ctx.outcome.document
    if doc and doc.get("checksum"):
        rows.append(row("Parameter file", f"written {doc.get('created', '')}, {doc['checksum']}"))
    from station.fitting.batch import frame_statement

    try:
        frame = frame_statement(trace)
    except Exception:  # noqa: BLE001
        frame = None
    if frame:
        qm = ", ".join(_num(v) for v in frame["origin_qm"])
        rows.append(row("Base frame", frame["statement"] + ".",
                        lines=[f"origin_qm = [{qm}] (actuator units)"]))
    return rows


def headline(ctx: "_Context", validation: list) -> str:
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


def _notes(ctx: _Context) -> list[str]:
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
    infl = [n for n, g in zip(ctx.names, ctx.groups) if g == "influence"]
    if infl:
        notes.append("not identifiable and influencing the model: " + ", ".join(infl)
                     + "; kept at their start values, on which the other calibrated values "
                       "depend")
    return list(dict.fromkeys(notes))


def _param_view(ctx: _Context) -> dict:
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
            inverse = (_num(1.0 / (x * f), ".6g") if name[:1] == "k" and name[1:].isdigit()
                       and _finite(x) and x != 0 else None)
            s0, x, std, change = s0 * f, x * f, std * f, change * f
            rows.append({"name": name, "unit": ctx.display.label(si) if si else "",
                         "nominal": _num(nom[j] * f) if nom is not None else None,
                         "start": _num(s0), "calibrated": _num(x), "inverse": inverse,
                         "std": _num(std, ".3g"),
                         "change": _num(change, "+.4g") if change else _num(change),
                         "significance": _num(sig, ".3g"), "label": label.lower()})
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


def _channel_view(ctx: _Context) -> dict:
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


def _validation_view(rows: list, units) -> dict:
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


def _design_view(ctx: _Context, evs, val_rows, units) -> dict | None:
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
                     "predicted": _num(p * f, ".3g"), "achieved": _num(a * f, ".3g"),
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


def _merge_events(recorded, given) -> list:
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


def _events_view(evs, units) -> dict:
    """The events table (plans by reference) and each plan's poses as its own table."""
    rows, plans = [], []
    for ev in evs:
        kind = str(ev.get("kind", ""))
        extra = {k: v for k, v in ev.items()
                 if k not in ("t", "kind", "message", "record", "poses")}
        poses = ev.get("poses") if isinstance(ev.get("poses"), list) else None
        details = short(extra) if extra else ""
        if poses is not None:
            plans.append(_plan_view(len(plans) + 1, ev, poses))
            details = (details + "; " if details else "") + f"poses: plan {len(plans)} below"
        rows.append({"t": short(ev.get("t", "")), "kind": short(kind),
                     "message": short(ev.get("message", "")), "details": short(details),
                     "fault": kind.lower() in ("fault", "error", "abort")})
    return {"rows": rows, "plans": plans}


def _plan_view(number: int, ev: dict, poses: list) -> dict:
    out = []
    for p in poses:
        if not isinstance(p, dict):
            continue
        out.append({"index": short(p.get("index")),
                    "qm": short(", ".join(_num(v, ".5g") for v in p.get("qm") or ())),
                    "target": short(", ".join(_num(v, ".4g") for v in p.get("target") or ())),
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
