"""The calibration report: one self-contained HTML file (``app.py batch --report``).

What a robotics engineer looks at after a calibration: the fit in one summary
(robot, method, trace and its SHA-256, poses against eq. 60, convergence, sigma
per channel, condition number, the held-out validation in one line, the
sm-distance-tilt base frame), the parameter table grouped by identifiability as
in the report's Table 3, the figures of the report's section 7 (parameter
convergence, variance and condition number per iteration), the residuals per
channel before and after calibration, and, when given, held-out validation, the
session's events (each plan as its own compact table) and the station setup.

The numbers come from :mod:`station.outputs.report_context` and
:mod:`station.outputs.report_sections`;
the page itself is the Jinja2 template ``station/templates/report.html.j2``
(autoescaped: every text from a trace, a session or an event is escaped) and the
figures come from :mod:`station.outputs.report_figures`. Numbers for people are in the
display units of :mod:`station.outputs.units` (mm and degrees by default), parameters in
SI as in the parameter file. No table cell is longer than
:data:`~station.outputs.report_context.CELL_MAX` characters. The file needs nothing else and opens offline; it is written
atomically (temporary file, fsync, rename), so a failure leaves no partial report.
"""
from __future__ import annotations

import contextlib
import dataclasses
import functools
import gc
import os
from pathlib import Path

from calibration.errors import StationError
from drivers.atomic import check_writable, write_atomic
from station.outputs import report_figures as figs
from station.outputs.fit_summary import outcome_document
from station.outputs.params_file import checksum, write_params
from station.outputs.report_context import ReportContext, short
from station.outputs.report_sections import (channel_view, design_view, events_view, headline,
                                             merge_events, notes, param_view, quality_view,
                                             summary_view, validation_view)
from station.outputs.units import MM_DEG

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


@functools.cache
def template_environment():
    """The Jinja2 environment of the report templates (package data of ``station``),
    made once per process (it keeps the compiled template)."""
    import jinja2

    return jinja2.Environment(
        loader=jinja2.PackageLoader("station", "templates"),
        autoescape=True, trim_blocks=True, lstrip_blocks=True,
        undefined=jinja2.StrictUndefined)


@contextlib.contextmanager
def collector_paused():
    """The cyclic garbage collector off while the report is built (as it was after).
    Matplotlib makes tens of thousands of short-lived objects per report; with the
    collector on they are scanned, promoted and trigger a full collection of the
    whole process' heap (about 0.15 s after an AGEBOT session, measured); made while it
    is off they stay young, and the next young collection frees them."""
    was = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if was:
            gc.enable()


def render_report(outcome, *, validation=None, events=(), title=None, session=None,
                  units=MM_DEG) -> str:
    """The report's HTML text (see :func:`write_report`)."""
    try:
        from matplotlib.backends.backend_agg import FigureCanvasAgg  # noqa: F401
        import jinja2  # noqa: F401
    except ModuleNotFoundError as e:
        raise ReportError(f"the HTML report needs {e.name} (a dependency of this package): "
                          "pip install -e .") from None
    ctx = ReportContext(outcome, units)
    title = title or (f"Calibration report: {ctx.robot}, {ctx.method}"
                      + (f", {ctx.trace_name}" if ctx.trace_name else ""))
    val_rows = [dict(v) for v in validation or () if isinstance(v, dict)]
    evs = merge_events(getattr(outcome.trace, "events", ()) or (), events or ())
    with collector_paused():
        page = _page(outcome, ctx, title, val_rows, evs, session, units)
    return template_environment().get_template(TEMPLATE).render(**page)


def _page(outcome, ctx, title, val_rows, evs, session, units) -> dict:
    return {
        "title": title,
        "headline": headline(ctx, val_rows),
        "created": ctx.created,
        "summary": summary_view(ctx, val_rows),
        "notes": notes(ctx),
        "quality": quality_view(outcome),
        "params": param_view(ctx),
        "channels": channel_view(ctx),
        "figures": figs.figures(ctx),
        "history": bool(list(outcome.result.history)),
        "validation": validation_view(val_rows, units) if val_rows else None,
        "design": design_view(ctx, evs, val_rows, units),
        "events": events_view(evs, units, outcome.model.robot) if evs else None,
        "session": ([(str(k), short(v)) for k, v in session.items()]
                    if isinstance(session, dict) else [("session", short(session))])
        if session else None,
    }


def write_outputs(outcome, trace_path: str | None, out, report=None,
                  **report_options):
    """Write the parameter file ``out`` and, if given, the HTML ``report``: both or
    neither (the report first; removed again if the parameter file cannot be
    written). Returns the outcome with its document."""
    doc = outcome_document(outcome, trace_path)
    doc["checksum"] = checksum(doc)
    outcome = dataclasses.replace(outcome, document=doc)
    if report:
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
