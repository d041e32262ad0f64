"""The calibration report: one self-contained HTML file (``app.py batch --report``).

What a robotics engineer looks at after a calibration: the fit in one header
(robot, method, trace and its SHA-256, poses against eq. 60, convergence, sigma
per channel, condition number, the sm-distance-tilt base frame), the parameter
table grouped by identifiability as in the report's Table 3, the figures of the
report's section 7 (parameter convergence, variance and condition number per
iteration), the residuals per channel before and after calibration, and,
when given, held-out validation, the session's events and the station setup.

Figures are PNG images embedded as base64 (matplotlib, Agg canvas; pyplot and
its global state are not used), styles are inline: the file needs nothing else
and opens offline. Every text from a trace, a session or an event is escaped.
The file is written atomically (temporary file, fsync, rename), so a failure
leaves no partial report.
"""
from __future__ import annotations

import base64
import copy
import html
import io
import json
import math
import os
from pathlib import Path

import numpy as np

from calibration import identifiability as ident
from calibration.errors import StationError
from drivers.atomic import write_atomic
from station.params_file import file_sha256
from station.trace import utc_now

IDENT_GROUPS = (
    ("identifiable", "Identifiable",
     "calibrated; the std is the square root of the covariance diagonal (eq. 52)"),
    ("no-influence", "Not identifiable, without influence",
     ("the measurements do not depend on it: kept at its start value, and a wrong start "
      "value does not bias the others")),
    ("influence", "Not identifiable, with influence",
     ("a combination of other columns: kept at its start value, and a wrong start value "
      "biases the others, so it must be known")),
)
# Table 3 symbols
IDENT_SYMBOL = {"identifiable": "\u2713", "no-influence": "\u25cb", "influence": "\u25cf"}

# units of the parameters (SI, as in the parameter file)
PARAM_UNITS = {
    "agebot-sm": {"q1_off": "m", "q2_off": "rad", "q3_off": "rad", "q4_off": "rad",
                  "k1": "m/u", "k2": "rad/u", "k3": "rad/u", "k4": "rad/u",
                  "L2": "m", "L3": "m", "L4": "m", "theta0": "rad", "a0": "m",
                  "plane_a": "1/m", "plane_b": "1/m", "plane_c": "1/m"},
    "agebot-pm": {"a1": "m", "a2": "m", "l": "m", "v": "m",
                  "q1_off": "m", "q2_off": "m", "q3_off": "m",
                  "k1": "m/u", "k2": "m/u", "k3": "m/u", "mount_x": "rad", "mount_y": "rad"},
}
# residual channel -> SI unit of one row
CHANNEL_UNITS = {"distance": "m", "tilt": "rad", "x": "m", "y": "m", "z": "m", "phi": "rad",
                 "alpha": "rad", "beta": "rad", "gamma": "rad", "roll": "rad", "pitch": "rad",
                 "q1": "actuator units", "q2": "actuator units", "q3": "actuator units",
                 "dx": "m", "dy": "m", "plane": "1"}
# SI unit -> (display unit, factor) for residuals and sigmas
DISPLAY = {"m": ("mm", 1e3), "rad": ("mrad", 1e3), "m\u00b2": ("mm\u00b2", 1e6)}

DPI = 96
COLORS = ("#1f77b4", "#d62728", "#2ca02c", "#ff7f0e", "#9467bd", "#8c564b", "#e377c2",
          "#7f7f7f", "#bcbd22", "#17becf", "#393b79", "#637939", "#843c39", "#7b4173",
          "#3182bd", "#e6550d")


class ReportError(StationError):
    """The report could not be made or written; nothing was left behind."""


# -- public ---------------------------------------------------------------------
def write_report(path, outcome, *, validation=None, events=(), title=None,
                 session=None) -> Path:
    """Write the HTML report of a batch outcome (:class:`station.batch.BatchOutcome`)
    atomically to ``path`` and return the path.

    validation: held-out poses, a list of dicts ``{"channel", "unit", "n", "rms_before",
                "rms_after", "max_before", "max_after"}`` (table and bar chart).
    events:     event records (dicts with ``t``, ``kind``, ``message``) shown with the
                trace's own events (exact repeats once).
    title:      the page title (default: robot, method and trace file).
    session:    free key/values (station config, devices, operator...), a small table.
    """
    path = Path(path)
    _check_writable(path)  # before the figures: fail fast
    text = render_report(outcome, validation=validation, events=events, title=title,
                         session=session)
    try:
        write_atomic(path, text.encode("utf-8"))
    except OSError as e:
        reason = e.strerror or str(e)
        raise ReportError(f"cannot write the report {path}: {reason}") from None
    return path


def _check_writable(path: Path) -> None:
    folder = path.parent if str(path.parent) else Path(".")
    reason = None
    if not folder.is_dir():
        reason = f"the folder {folder} does not exist"
    elif path.is_dir():
        reason = "it is a folder"
    elif not os.access(folder, os.W_OK | os.X_OK):
        reason = f"no permission to write in {folder}"
    if reason:
        raise ReportError(f"cannot write the report {path}: {reason}")


def render_report(outcome, *, validation=None, events=(), title=None, session=None) -> str:
    """The report's HTML text (see :func:`write_report`)."""
    try:
        from matplotlib.backends.backend_agg import FigureCanvasAgg  # noqa: F401
    except ModuleNotFoundError:
        raise ReportError("the HTML report needs matplotlib (a dependency of this package): pip install -e .") from None
    ctx = _Context(outcome)
    title = title or (f"Calibration report: {ctx.robot}, {ctx.method}"
                      + (f", {ctx.trace_name}" if ctx.trace_name else ""))
    parts = [_header(ctx), _notes(ctx), _param_section(ctx), _channel_section(ctx),
             _figures(ctx)]
    if validation:
        parts.append(_validation_section(validation))
    evs = _merge_events(getattr(outcome.trace, "events", ()) or (), events or ())
    if evs:
        parts.append(_events_section(evs))
    if session:
        parts.append(_session_section(session))
    body = "\n".join(p for p in parts if p)
    return (
        "<!DOCTYPE html>\n<html lang=\"en\">\n<head>\n<meta charset=\"utf-8\">\n"
        "<meta name=\"viewport\" content=\"width=device-width, initial-scale=1\">\n"
        "<meta name=\"generator\" content=\"calstation station.report\">\n"
        f"<title>{_e(title)}</title>\n<style>{CSS}</style>\n</head>\n<body>\n<main>\n"
        f"<h1>{_e(title)}</h1>\n{body}\n"
        f"<footer>Generated {_e(ctx.created)} by the calibration station "
        "(station/report.py). Method: linearized iterative least squares, Algorithm 2 of "
        "the technical report.</footer>\n</main>\n</body>\n</html>\n")


# -- data -----------------------------------------------------------------------
class _Context:
    """What the sections share, computed once."""

    def __init__(self, outcome):
        self.outcome = outcome
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
        self.groups = [_group(st) for st in res.status]
        nom = getattr(model, "nominal", None)
        try:
            nom = np.asarray(nom, dtype=float) if nom is not None else None
        except (TypeError, ValueError):
            nom = None
        # the nominal as given, where the method re-estimated start values from it
        self.given_nominal = (nom if nom is not None and nom.shape == self.start.shape
                              and not np.array_equal(nom, self.start)
                              else None)
        self.units = PARAM_UNITS.get(self.robot, {})
        self.trace_path = getattr(self.trace, "path", None)
        self.trace_name = os.path.basename(self.trace_path) if self.trace_path else ""
        self.channels = tuple(model.channels)
        self.row_channel = np.asarray(model.row_channel)
        squared = getattr(model, "residual", "plain") == "squared"
        self.channel_unit = {ch: ("m\u00b2" if ch == "distance" and squared
                                  else CHANNEL_UNITS.get(ch, "")) for ch in self.channels}
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
        from station.batch import solver_sigma

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


def _group(st) -> str:
    if st.identifiable:
        return "identifiable"
    return "influence" if st.influences_model else "no-influence"


# -- formatting -------------------------------------------------------------------
def _e(v) -> str:
    return html.escape(str(v), quote=True)


def _finite(v) -> bool:
    try:
        return v is not None and not isinstance(v, bool) and math.isfinite(float(v))
    except (TypeError, ValueError):
        return False


def _num(v, fmt=".7g") -> str:
    if not _finite(v):
        return "\u2013"
    return format(float(v), fmt)


def _any(v, fmt=".4g") -> str:
    """A number formatted, anything else as text (escaped by the caller)."""
    if isinstance(v, bool):
        return str(v)
    if isinstance(v, (int, np.integer)):
        return str(int(v))
    if isinstance(v, (float, np.floating)):
        return _num(v, fmt)
    if v is None:
        return "\u2013"
    if isinstance(v, (dict, list, tuple)):
        try:
            return json.dumps(v, ensure_ascii=False, default=str)
        except (TypeError, ValueError):
            return str(v)
    return str(v)


def _display(unit: str):
    return DISPLAY.get(unit, (unit, 1.0))


def _kv_table(rows, cls="kv") -> str:
    out = [f'<table class="{cls}">']
    for k, v, *raw in rows:
        val = v if raw and raw[0] else _e(v)
        out.append(f"<tr><th>{_e(k)}</th><td>{val}</td></tr>")
    out.append("</table>")
    return "\n".join(out)


def _badge(ok: bool, yes: str, no: str) -> str:
    return (f'<span class="badge ok">{_e(yes)}</span>' if ok
            else f'<span class="badge bad">{_e(no)}</span>')


# -- sections ----------------------------------------------------------------------
def _header(ctx: _Context) -> str:
    res, model, trace = ctx.res, ctx.model, ctx.trace
    from calibration.methods import METHODS

    mi = METHODS.get(ctx.method)
    method = ctx.method + (f" (report section {mi.section})" if mi and mi.section else "")
    residual_form = getattr(model, "residual", None)
    if residual_form:
        method += (", residual D_M - D (plain)" if residual_form == "plain"
                   else ", residual D_M\u00b2 - D\u00b2 (squared, report eqs. 63, 83)")
    n_poses = int(model.n_poses)
    enough = n_poses >= ctx.min_poses
    poses = (f"{n_poses} poses, {int(res.n_rows or len(ctx.after))} rows, "
             f"p = {int(model.p)} (eq. 60) "
             + _badge(enough, f"eq. 60 minimum {ctx.min_poses} met",
                      f"below the eq. 60 minimum of {ctx.min_poses}"))
    rows = [
        ("Robot", ctx.robot),
        ("Method", method),
        ("Trace", ctx.trace_name or "(not from a file)"),
        ("Trace SHA-256", ctx.trace_sha256()
         + (" (as in the parameter file)" if (ctx.outcome.document or {}).get("source_trace")
            else "")),
        ("Trace recorded", trace.header.get("created", "\u2013")),
        ("Report created", ctx.created),
        ("Poses", poses, True),
        ("Eq. 60 minimum poses", (f"m \u2265 5 N_R / p = 5 \u00b7 {res.n_identifiable} / "
                                  f"{int(model.p)} \u2192 {ctx.min_poses}")),
        ("Identifiable parameters", f"N_R = {res.n_identifiable} of {len(ctx.names)}"),
        ("Converged", _badge(bool(res.converged), "converged", "NOT converged")
         + f" {_e(res.message)}", True),
        ("Iterations", (f"{int(res.iterations)} ({int(res.nfev)} model evaluations, "
                        f"{res.wall_time:.3g} s)")),
        ("Condition number", (f"{_num(res.condition_number, '.4g')} (scaled, weighted "
                              "observation matrix at the solution)")),
        ("Sigma", ("known: from the trace, used as the weights" if res.sigma_known else
                   "estimated per channel at the solution (eq. 51)")),
    ]
    if getattr(trace, "truncated_tail", False):
        rows.append(("Trace warning",
                     "the last line was truncated (recording interrupted) and skipped"))
    station = trace.header.get("station")
    if station:
        rows.append(("Trace station record", _any(station)))
    doc = ctx.outcome.document
    if doc and doc.get("checksum"):
        rows.append(("Parameter file", f"written {doc.get('created', '')}, {doc['checksum']}"))
    from station.batch import frame_statement

    try:
        frame = frame_statement(trace)
    except Exception:  # noqa: BLE001
        frame = None
    if frame:
        qm = ", ".join(_num(v) for v in frame["origin_qm"])
        rows.append(("Base frame", f"{_e(frame['statement'])}.<br>origin_qm = [{_e(qm)}]",
                     True))
    return '<section id="summary">\n<h2>Summary</h2>\n' + _kv_table(rows) + "\n</section>"


def _notes(ctx: _Context) -> str:
    model, res = ctx.model, ctx.res
    notes = []
    op = getattr(model, "operator_notes", None)
    try:
        notes += list(op(ctx.x)) if callable(op) else list(getattr(model, "notes", ()) or ())
    except Exception:  # noqa: BLE001
        notes += list(getattr(model, "notes", ()) or ())
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
    seen, uniq = set(), []
    for n in notes:
        if n not in seen:
            seen.add(n)
            uniq.append(n)
    if not uniq:
        return ""
    items = "\n".join(f"<li>{_e(n)}</li>" for n in uniq)
    return f'<section id="notes">\n<h2>Notes</h2>\n<ul class="notes">\n{items}\n</ul>\n</section>'


def _param_section(ctx: _Context) -> str:
    names, groups = ctx.names, ctx.groups
    # Table 3 strip: one row, a column per parameter
    head = "".join(f"<th>{_e(n)}</th>" for n in names)
    titles = {k: t.lower() for k, t, _ in IDENT_GROUPS}
    cells = "".join(f'<td class="sym {g}" title="{_e(titles[g])}">{IDENT_SYMBOL[g]}</td>'
                    for g in groups)
    legend = " &nbsp; ".join(f'<span class="sym {k}">{IDENT_SYMBOL[k]}</span> {_e(t.lower())}'
                             for k, t, _ in IDENT_GROUPS)
    strip = (f'<div class="scroll"><table class="table3"><tr><th>method</th>{head}</tr>'
             f"<tr><td>{_e(ctx.method)}</td>{cells}</tr></table></div>"
             f'<p class="legend">{legend}</p>')
    nom = ctx.given_nominal
    ncols = 8 + (nom is not None)
    out = ['<table class="params">',
           "<thead><tr><th>parameter</th><th>unit</th>"
           + ("<th>nominal (trace)</th>" if nom is not None else "")
           + "<th>start</th><th>calibrated</th><th>std</th><th>change</th><th>|change| / std</th>"
           "<th>identifiability</th></tr></thead><tbody>"]
    for key, label, expl in IDENT_GROUPS:
        idx = [j for j, g in enumerate(groups) if g == key]
        if not idx:
            continue
        out.append(f'<tr class="group {key}"><th colspan="{ncols}">{IDENT_SYMBOL[key]} {_e(label)} '
                   f'({len(idx)}) <span class="expl">\u2013 {_e(expl)}</span></th></tr>')
        for j in idx:
            name = names[j]
            s0, x = ctx.start[j], ctx.x[j]
            std = ctx.std[j] if key == "identifiable" else float("nan")
            change = x - s0
            sig = abs(change) / std if _finite(std) and std > 0 else float("nan")
            calibrated = _e(_num(x))
            if name[:1] == "k" and name[1:].isdigit() and _finite(x) and x != 0:
                calibrated += f' <span class="aux">= 1/{_e(_num(1.0 / x, ".6g"))}</span>'
            out.append(
                f'<tr><td class="name">{_e(name)}</td><td>{_e(ctx.units.get(name, ""))}</td>'
                + (f'<td class="num">{_e(_num(nom[j]))}</td>' if nom is not None else "") +
                f'<td class="num">{_e(_num(s0))}</td><td class="num">{calibrated}</td>'
                f'<td class="num">{_e(_num(std, ".3g"))}</td>'
                f'<td class="num">{_e(_num(change, "+.4g") if change else _num(change))}</td>'
                f'<td class="num">{_e(_num(sig, ".3g"))}</td><td>{_e(label.lower())}</td></tr>')
    out.append("</tbody></table>")
    unit_note = ("<p class=\"legend\">Units SI as in the parameter file; u = actuator unit "
                 "(the transmission Q = K\u00b7Qm + Q_off). Start = the values the iteration "
                 "started from" + (": the method computed them from the trace's nominal "
                                   "(sm-distance-tilt: the nominal in the chosen base frame, "
                                   "eqs. 76-77; PM: a robust start fitted to the data); the "
                                   "residuals \u201cbefore\u201d are at these start values; "
                                   "change = calibrated \u2212 start." if nom is not None else
                                   " (the nominal); change = calibrated \u2212 start.")
                 + "</p>")
    return ('<section id="parameters">\n<h2>Parameters and identifiability</h2>\n'
            + strip + "\n" + "\n".join(out) + "\n" + unit_note + "\n</section>")


def _channel_section(ctx: _Context) -> str:
    res = ctx.res
    given, est = ctx.sigma_given(), ctx.sigma_estimated()
    out = [('<table class="channels"><thead><tr><th>channel</th><th>unit</th><th>rows</th>'
            "<th>sigma given (trace)</th><th>sigma estimated (eq. 51)</th><th>sigma used</th>"
            "<th>RMS before</th><th>RMS after</th><th>max |after|</th></tr></thead><tbody>")]
    for c, ch in enumerate(ctx.channels):
        unit, f = _display(ctx.channel_unit[ch])
        sel = ctx.rows_of(c)
        a = ctx.after[sel]
        b = ctx.before[sel] if ctx.before is not None else None

        def v(x, fmt=".4g", f=f):
            return _e(_num(x * f if _finite(x) else x, fmt))

        rms_b = float(np.sqrt(np.mean(b ** 2))) if b is not None and b.size else None
        rms_a = float(np.sqrt(np.mean(a ** 2))) if a.size else None
        mx_a = float(np.max(np.abs(a))) if a.size else None
        used = res.sigma.get(ch)
        out.append(f"<tr><td class=\"name\">{_e(ch)}</td><td>{_e(unit)}</td>"
                   f"<td class=\"num\">{int(sel.sum())}</td>"
                   f"<td class=\"num\">{v(given.get(ch))}</td>"
                   f"<td class=\"num\">{v(est.get(ch))}</td><td class=\"num\">{v(used)}</td>"
                   f"<td class=\"num\">{v(rms_b)}</td><td class=\"num\">{v(rms_a)}</td>"
                   f"<td class=\"num\">{v(mx_a)}</td></tr>")
    out.append("</tbody></table>")
    text = ("<p class=\"legend\">Residual = measured \u2212 predicted. Before: at the start "
            "values; after: at the calibrated values. Sigma is the standard deviation of one "
            "row; \u201cused\u201d is what weighted the fit and the covariance ("
            + ("known from the trace" if res.sigma_known else "estimated at the solution")
            + ").</p>")
    if ctx.before_error:
        text += (f"<p class=\"warn\">The residual at the start values could not be evaluated: "
                 f"{_e(ctx.before_error)}</p>")
    return ('<section id="channels">\n<h2>Measurement channels</h2>\n' + "\n".join(out)
            + "\n" + text + "\n</section>")


# -- figures --------------------------------------------------------------------------
def _figure(width, height, **margins):
    """A figure on its own Agg canvas (no pyplot). Margins are fixed, in inches
    (left, right, bottom, top), plus ``wspace``/``hspace``: cheaper than a layout
    engine and the same for every report."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width, height), dpi=DPI)
    FigureCanvasAgg(fig)
    m = {"left": 0.75, "right": 0.2, "bottom": 0.5, "top": 0.3, **margins}
    fig.subplots_adjust(left=m["left"] / width, right=1 - m["right"] / width,
                        bottom=m["bottom"] / height, top=1 - m["top"] / height,
                        wspace=m.get("wspace", 0.2), hspace=m.get("hspace", 0.2))
    return fig


def _png(fig) -> str:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=DPI, metadata={"Software": None})
    return base64.b64encode(buf.getvalue()).decode("ascii")


def _img(fig, alt: str, caption: str) -> str:
    return (f'<figure><img src="data:image/png;base64,{_png(fig)}" alt="{_e(alt)}">'
            f"<figcaption>{_e(caption)}</figcaption></figure>")


def _style(ax, fs=8):
    ax.tick_params(which="both", labelsize=fs)
    ax.grid(True, which="major", alpha=0.35, linewidth=0.6)
    for side in ("top", "right"):
        ax.spines[side].set_visible(False)


def _marker(n):
    return "o" if n <= 60 else None


def _figures(ctx: _Context) -> str:
    hist = list(ctx.res.history)
    figs = []
    if hist:
        figs.append(_fig_parameters(ctx, hist))
        figs.append(_fig_deviation(ctx, hist))
        figs.append(_fig_variance(ctx, hist))
        figs.append(_fig_condition(ctx, hist))
    figs.append(_fig_residuals(ctx))
    body = "\n".join(f for f in figs if f)
    if not hist:
        body = "<p class=\"warn\">The solver recorded no iterations.</p>\n" + body
    return f'<section id="figures">\n<h2>Figures</h2>\n{body}\n</section>'


def _series(ctx, hist):
    """Iterations 0..K and the parameters there (row 0: the start values)."""
    X = np.vstack([np.asarray(ctx.res.x0, dtype=float)] + [np.asarray(h.x, dtype=float)
                                                           for h in hist])
    return np.arange(len(X)), X


def _active(ctx):
    return [j for j, g in enumerate(ctx.groups) if g == "identifiable"]


def _fig_parameters(ctx, hist) -> str:
    idx = _active(ctx)
    if not idx:
        return ""
    k, X = _series(ctx, hist)
    ncol = 4 if len(idx) > 6 else min(3, len(idx))
    nrow = math.ceil(len(idx) / ncol)
    fig = _figure(2.5 * ncol, 1.8 * nrow + 0.5, left=0.6, bottom=0.55, top=0.3,
                  wspace=0.55, hspace=0.6)
    axes = fig.subplots(nrow, ncol, squeeze=False)
    for a, j in enumerate(idx):
        ax = axes[a // ncol][a % ncol]
        x_end, s = ctx.x[j], ctx.std[j]
        if _finite(s) and s > 0:
            ax.axhspan(x_end - s, x_end + s, color="#d62728", alpha=0.15, lw=0)
        ax.axhline(x_end, color="#d62728", lw=0.8, ls="--")
        ax.plot(k, X[:, j], color="#1f77b4", lw=1.2, marker=_marker(len(k)), ms=2.5)
        unit = ctx.units.get(ctx.names[j], "")
        ax.set_title(f"{ctx.names[j]}" + (f" [{unit}]" if unit else ""), fontsize=8)
        _style(ax, 7)
        ax.ticklabel_format(axis="y", useOffset=False, style="sci", scilimits=(-3, 4))
        ax.yaxis.get_offset_text().set_fontsize(7)
    for a in range(len(idx), nrow * ncol):
        axes[a // ncol][a % ncol].set_visible(False)
    fig.supxlabel("iteration k", fontsize=8, y=0.01)
    return _img(fig, "parameter values per iteration",
                "Calibrated parameters \u03be(k) per iteration (k = 0: start values); dashed: "
                "the calibrated value, band: \u00b1 1 std (report Fig. 10, 28).")


def _fig_deviation(ctx, hist) -> str:
    idx = [j for j in _active(ctx) if _finite(ctx.std[j]) and ctx.std[j] > 0]
    if not idx:
        return ""
    k, X = _series(ctx, hist)
    fig = _figure(10.0, 3.6, right=1.7, left=0.8)
    ax = fig.subplots()
    floor = 1e-6
    for n, j in enumerate(idx):
        d = np.abs(X[:, j] - ctx.x[j]) / ctx.std[j]
        ax.semilogy(k, np.maximum(d, floor), color=COLORS[n % len(COLORS)], lw=1.1,
                    marker=_marker(len(k)), ms=2.5, label=ctx.names[j])
    ax.axhline(1.0, color="k", lw=0.8, ls="--")
    ax.text(k[-1], 1.0, " 1 std", va="bottom", ha="right", fontsize=7)
    ax.set_xlabel("iteration k", fontsize=8)
    ax.set_ylabel("|\u03be(k) \u2212 \u03be_final| / std", fontsize=8)
    ax.set_ylim(bottom=floor / 2)
    _style(ax)
    ax.legend(fontsize=7, ncol=max(1, math.ceil(len(idx) / 8)), loc="upper left",
              bbox_to_anchor=(1.01, 1.0), frameon=False)
    return _img(fig, "parameter deviation from the final value in standard deviations",
                f"Convergence: distance of each identifiable parameter from its calibrated value "
                f"in units of its std (values below {floor:g} drawn at {floor:g}).")


def _fig_variance(ctx, hist) -> str:
    V = np.array([np.asarray(h.variance, dtype=float) for h in hist])
    k = np.arange(1, len(hist) + 1)
    cols = [j for j in range(V.shape[1]) if np.any(np.isfinite(V[:, j]) & (V[:, j] > 0))]
    if not cols:
        return ""
    fig = _figure(10.0, 3.6, right=1.7, left=0.8)
    ax = fig.subplots()
    for n, j in enumerate(cols):
        v = np.where(V[:, j] > 0, V[:, j], np.nan)
        ax.semilogy(k, v, color=COLORS[n % len(COLORS)], lw=1.1, marker=_marker(len(k)),
                    ms=2.5, label=ctx.names[j])
    ax.set_xlabel("iteration k", fontsize=8)
    ax.set_ylabel("variance [SI units\u00b2]", fontsize=8)
    _style(ax)
    ax.legend(fontsize=7, ncol=max(1, math.ceil(len(cols) / 8)), loc="upper left",
              bbox_to_anchor=(1.01, 1.0), frameon=False)
    return _img(fig, "variance per iteration",
                "Variance of each calibrated parameter per iteration, Var(e(k)) (eq. 52; "
                "report Fig. 11, 29). Gaps: the parameter was not calibrated in that iteration.")


def _fig_condition(ctx, hist) -> str:
    c = np.array([float(h.condition_number) for h in hist])
    k = np.arange(1, len(hist) + 1)
    ok = np.isfinite(c) & (c > 0)
    if not ok.any():
        return ""
    fig = _figure(10.0, 2.8, right=1.7, left=0.8)
    ax = fig.subplots()
    ax.plot(k[ok], c[ok], color="#1f77b4", lw=1.2, marker=_marker(len(k)), ms=2.5)
    if c[ok].max() / c[ok].min() > 10:
        ax.set_yscale("log")
    else:
        ax.ticklabel_format(axis="y", useOffset=False, style="plain")
    if _finite(ctx.res.condition_number) and ctx.res.condition_number > 0:
        ax.axhline(ctx.res.condition_number, color="#d62728", lw=0.8, ls="--")
        ax.text(k[-1], ctx.res.condition_number,
                f" at the solution {ctx.res.condition_number:.4g}", va="bottom", ha="right",
                fontsize=7)
    ax.set_xlabel("iteration k", fontsize=8)
    ax.set_ylabel("condition number", fontsize=8)
    _style(ax)
    return _img(fig, "condition number per iteration",
                "Condition number of the scaled, weighted observation matrix per iteration "
                "(report Fig. 12, 30).")


PREFIX = {0: "", -3: "m", -6: "\u00b5", -9: "n", -12: "p", -15: "f"}


def _scale(values, unit: str):
    """(factor, unit label) that bring ``values`` (SI) to a readable range:
    an SI prefix for m and rad (mm\u00b2 for the squared distance), a power of
    ten for anything else."""
    v = np.asarray(values, dtype=float)
    v = np.abs(v[np.isfinite(v)])
    m = float(v.max()) if v.size else 0.0
    if unit == "m\u00b2":
        return 1e6, "mm\u00b2"
    if m <= 0:
        return (1e3, PREFIX[-3] + unit) if unit in ("m", "rad") else (1.0, unit)
    e = math.floor(math.log10(m) / 3.0) * 3
    if unit in ("m", "rad"):
        e = min(0, max(-15, e))
        return 10.0 ** -e, PREFIX[e] + unit
    if e == 0:
        return 1.0, unit
    return 10.0 ** -e, (f"{unit} \u00d7 1e{e}" if unit and unit != "1" else f"\u00d7 1e{e}")


def _fig_residuals(ctx) -> str:
    chans = list(enumerate(ctx.channels))
    if not chans or ctx.after.size == 0:
        return ""
    has_before = ctx.before is not None
    ncol = 3 if has_before else 2
    fig = _figure(10.0, 2.2 * len(chans) + 0.4, left=0.8, bottom=0.55, top=0.3,
                  wspace=0.3, hspace=0.6)
    axes = fig.subplots(len(chans), ncol, squeeze=False)
    for row, (c, ch) in enumerate(chans):
        si = ctx.channel_unit[ch]
        sel = ctx.rows_of(c)
        s = ctx.res.sigma.get(ch)
        s = float(s) if _finite(s) and s > 0 else 0.0
        after = ctx.after[sel]
        f, unit = _scale(np.append(after, s), si)
        a = after * f
        sf = s * f
        i = np.arange(a.size)
        col = 0
        if has_before:
            fb, ub = _scale(ctx.before[sel], si)
            b = ctx.before[sel] * fb
            ax = axes[row][col]
            ax.vlines(i, 0, b, color="#7f7f7f", lw=1.0)
            ax.plot(i, b, "o", color="#7f7f7f", ms=2.5)
            ax.axhline(0, color="k", lw=0.6)
            ax.set_title(f"{ch}: before (start values)", fontsize=8)
            ax.set_ylabel(f"residual [{ub}]" if ub else "residual", fontsize=8)
            _style(ax, 7)
            col += 1
        ax = axes[row][col]
        ax.vlines(i, 0, a, color="#1f77b4", lw=1.0)
        ax.plot(i, a, "o", color="#1f77b4", ms=2.5)
        ax.axhline(0, color="k", lw=0.6)
        if sf > 0:
            for sgn in (-1, 1):
                ax.axhline(sgn * sf, color="#d62728", lw=0.7, ls="--")
        ax.set_title(f"{ch}: after (calibrated)", fontsize=8)
        ax.set_ylabel(f"residual [{unit}]" if unit else "residual", fontsize=8)
        _style(ax, 7)
        ax = axes[row][col + 1]
        nb = int(min(30, max(8, math.sqrt(max(a.size, 1)) * 1.5)))
        lo, hi = (float(a.min()), float(a.max())) if a.size else (0.0, 0.0)
        if sf > 0:
            lo, hi = min(lo, -3 * sf), max(hi, 3 * sf)
        if not hi > lo:
            lo, hi = lo - 0.5, hi + 0.5
        edges = np.linspace(lo, hi, nb + 1)
        ax.hist(a, bins=edges, color="#1f77b4", alpha=0.75, edgecolor="white", linewidth=0.5)
        if sf > 0 and a.size > 1:
            xs = np.linspace(lo, hi, 200)
            pdf = np.exp(-0.5 * (xs / sf) ** 2) / (sf * math.sqrt(2 * math.pi))
            ax.plot(xs, pdf * a.size * float(edges[1] - edges[0]), color="#d62728", lw=1.0)
        ax.set_title(f"{ch}: after, histogram", fontsize=8)
        ax.set_xlabel(f"residual [{unit}]" if unit else "residual", fontsize=8)
        _style(ax, 7)
        for ax in axes[row]:
            ax.ticklabel_format(useOffset=False, style="plain")
    for ax in axes[-1][: ncol - 1]:
        ax.set_xlabel("row (pose order)", fontsize=8)
    return _img(fig, "residuals per channel before and after calibration",
                "Residuals (measured \u2212 predicted) per channel, by row in pose order: at the "
                "start values, at the calibrated values (dashed: \u00b1 sigma used), and the "
                "histogram after calibration with the normal density of that sigma.")


# -- optional sections ----------------------------------------------------------------
VALIDATION_KEYS = ("channel", "unit", "n", "rms_before", "rms_after", "max_before", "max_after")


def _validation_section(validation) -> str:
    rows = [dict(v) for v in validation if isinstance(v, dict)]
    if not rows:
        return ""
    extra = sorted({k for v in rows for k in v} - set(VALIDATION_KEYS))
    out = [('<table class="validation"><thead><tr><th>channel</th><th>unit</th><th>n</th>'
            "<th>RMS before</th><th>RMS after</th><th>RMS change</th><th>max before</th>"
            "<th>max after</th>" + "".join(f"<th>{_e(k)}</th>" for k in extra)
            + "</tr></thead><tbody>")]
    for v in rows:
        rb, ra = v.get("rms_before"), v.get("rms_after")
        change = (f"{(float(ra) / float(rb) - 1) * 100:+.1f} %"
                  if _finite(rb) and _finite(ra) and float(rb) != 0 else "\u2013")
        cells = [f'<td class="name">{_e(_any(v.get(k)))}</td>' for k in ("channel", "unit")]
        cells += [f'<td class="num">{_e(_any(v.get(k)))}</td>'
                  for k in ("n", "rms_before", "rms_after")]
        cells.append(f'<td class="num">{_e(change)}</td>')
        cells += [f'<td class="num">{_e(_any(v.get(k)))}</td>' for k in ("max_before", "max_after")]
        cells += [f"<td>{_e(_any(v.get(k, '')))}</td>" for k in extra]
        out.append("<tr>" + "".join(cells) + "</tr>")
    out.append("</tbody></table>")
    fig = _fig_validation(rows)
    return ('<section id="validation">\n<h2>Validation on held-out poses</h2>\n'
            + "\n".join(out) + "\n" + fig + "\n</section>")


def _fig_validation(rows) -> str:
    good = [v for v in rows if _finite(v.get("rms_after")) and _finite(v.get("max_after"))]
    if not good:
        return ""
    ncol = min(4, len(good))
    nrow = math.ceil(len(good) / ncol)
    fig = _figure(2.6 * ncol + 0.4, 2.3 * nrow, left=0.7, bottom=0.35, top=0.3,
                  wspace=0.45, hspace=0.5)
    axes = fig.subplots(nrow, ncol, squeeze=False)
    for n, v in enumerate(good):
        ax = axes[n // ncol][n % ncol]
        pos = np.arange(2)
        vals = {when: [float(v[f"{what}_{when}"]) if _finite(v.get(f"{what}_{when}"))
                       else float("nan") for what in ("rms", "max")]
                for when in ("before", "after")}
        unit = str(v.get("unit") or "")
        f, unit = _scale([x for xs in vals.values() for x in xs if math.isfinite(x)], unit)
        for dx, when, color in ((-0.2, "before", "#7f7f7f"), (0.2, "after", "#1f77b4")):
            heights = [x * f for x in vals[when]]
            if not any(math.isfinite(x) for x in heights):
                continue
            bars = ax.bar(pos + dx, np.nan_to_num(heights), 0.4, color=color, label=when)
            ax.bar_label(bars, labels=[format(x, ".3g") if math.isfinite(x) else "n/a"
                                       for x in heights], fontsize=6, padding=1)
        ax.margins(y=0.12)
        ax.set_xticks(pos, ["RMS", "max"])
        ax.set_title(f"{v.get('channel')}" + (f" [{unit}]" if unit else ""), fontsize=8)
        ax.ticklabel_format(axis="y", useOffset=False, style="plain")
        _style(ax, 7)
        if n == 0:
            ax.legend(fontsize=7, frameon=False)
    for n in range(len(good), nrow * ncol):
        axes[n // ncol][n % ncol].set_visible(False)
    return _img(fig, "validation error before and after calibration",
                "Held-out poses: RMS and maximum error per channel before (start values) "
                "and after calibration.")


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


def _events_section(evs) -> str:
    out = [('<table class="events"><thead><tr><th>t</th><th>kind</th><th>message</th>'
            "<th>details</th></tr></thead><tbody>")]
    for ev in evs:
        extra = {k: v for k, v in ev.items() if k not in ("t", "kind", "message", "record")}
        kind = str(ev.get("kind", ""))
        cls = ' class="fault"' if kind.lower() in ("fault", "error", "abort") else ""
        out.append(f"<tr{cls}><td class=\"mono\">{_e(_any(ev.get('t', '')))}</td>"
                   f"<td>{_e(kind)}</td><td>{_e(_any(ev.get('message', '')))}</td>"
                   f"<td class=\"mono\">{_e(_any(extra)) if extra else ''}</td></tr>")
    out.append("</tbody></table>")
    return ('<section id="events">\n<h2>Events</h2>\n' + "\n".join(out) + "\n</section>")


def _session_section(session) -> str:
    items = session.items() if isinstance(session, dict) else [("session", session)]
    rows = [(str(k), _any(v)) for k, v in items]
    return '<section id="session">\n<h2>Session</h2>\n' + _kv_table(rows) + "\n</section>"


CSS = """
:root { --fg: #1d2330; --muted: #5b6475; --line: #d9dee7; --bg: #ffffff; --head: #f2f4f8;
        --ok: #1b7f3b; --bad: #b42318; --accent: #1f5fa8; }
* { box-sizing: border-box; }
body { margin: 0; background: var(--bg); color: var(--fg);
       font: 14px/1.45 system-ui, -apple-system, "Segoe UI", Roboto, "Helvetica Neue", Arial,
       sans-serif; }
main { max-width: 1120px; margin: 0 auto; padding: 24px 28px 40px; }
h1 { font-size: 22px; margin: 0 0 16px; border-bottom: 3px solid var(--accent);
     padding-bottom: 8px; }
h2 { font-size: 17px; margin: 28px 0 10px; color: var(--accent); }
table { border-collapse: collapse; margin: 6px 0 10px; font-size: 13px; }
th, td { border: 1px solid var(--line); padding: 4px 8px; text-align: left;
         vertical-align: top; }
thead th { background: var(--head); font-weight: 600; white-space: nowrap; }
tbody tr:nth-child(even) td { background: #fafbfd; }
table.kv th { background: var(--head); width: 220px; font-weight: 600; }
table.kv td { word-break: break-word; }
td.num { text-align: right; font-family: ui-monospace, "SFMono-Regular", Menlo, Consolas,
         monospace; font-variant-numeric: tabular-nums; white-space: nowrap; }
td.mono { font-family: ui-monospace, Menlo, Consolas, monospace; font-size: 12px; }
td.name { font-weight: 600; white-space: nowrap; }
.aux { color: var(--muted); font-size: 11px; }
tr.group th { text-align: left; font-size: 13px; background: #e8eef8; }
tr.group.no-influence th { background: #f1f1f1; }
tr.group.influence th { background: #fdf0e6; }
tr.group .expl { font-weight: normal; color: var(--muted); }
table.table3 td.sym, table.table3 th { text-align: center; }
.sym.identifiable { color: var(--ok); }
.sym.no-influence { color: var(--muted); }
.sym.influence { color: #c4570c; }
.scroll { overflow-x: auto; }
.legend { color: var(--muted); font-size: 12px; margin: 4px 0 10px; }
.badge { display: inline-block; padding: 0 7px; border-radius: 9px; font-size: 12px;
         font-weight: 600; color: #fff; }
.badge.ok { background: var(--ok); }
.badge.bad { background: var(--bad); }
.warn { color: var(--bad); }
ul.notes li { margin-bottom: 6px; }
tr.fault td { color: var(--bad); }
figure { margin: 14px 0 22px; }
figure img { max-width: 100%; height: auto; border: 1px solid var(--line); }
figcaption { color: var(--muted); font-size: 12px; margin-top: 4px; }
footer { margin-top: 36px; color: var(--muted); font-size: 12px; border-top: 1px solid
         var(--line); padding-top: 8px; }
@media print { main { max-width: none; padding: 0; } figure { break-inside: avoid; }
               h2 { break-after: avoid; } }
"""
