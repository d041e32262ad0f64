"""A calibration's result as the report shows it: the live convergence plots,
the identifiability table in the style of the report's Table 3 and the
validation errors before and after (used by the Calibrate and Offline pages)."""
from __future__ import annotations

import html
import math

from PySide6.QtCore import Qt
from PySide6.QtGui import QColor, QFont
from PySide6.QtWidgets import (QTableWidgetItem,
                               QVBoxLayout, QWidget)

from station.gui.plots import ConvergencePlots
from station.gui.tables import GROUP_COLOR, IdentifiabilityStrip, _spanned, _table
from station.outputs.fit_summary import describe_not_identified, not_identified, operator_notes
from station.gui.widgets import BAD_COLOR, OK_COLOR, WARN_COLOR, heading, note
from station.outputs.report_context import IDENT_GROUPS, IDENT_SYMBOL, group_of
from station.outputs.units import param_units
from station.outputs.units import MM_DEG, channel_si

STRIP_HEADING = "Identifiability (report Table 3)"


def _num(v, fmt=".7g") -> str:
    try:
        v = float(v)
    except (TypeError, ValueError):
        return "\u2013"
    return format(v, fmt) if math.isfinite(v) else "\u2013"


class CalibrationView(QWidget):
    """Plots while iterating, then the parameter table and the validation errors."""

    def __init__(self, parent=None):
        super().__init__(parent)
        lay = QVBoxLayout(self)
        lay.setContentsMargins(0, 0, 0, 0)
        self.plots = ConvergencePlots()
        lay.addWidget(self.plots)
        self.summary = note("")
        lay.addWidget(self.summary)
        self.quality = note("")
        lay.addWidget(self.quality)
        self.strip_heading = heading(STRIP_HEADING)
        lay.addWidget(self.strip_heading)
        self.strip = IdentifiabilityStrip()
        lay.addWidget(self.strip)
        legend = " \u2003 ".join(f"{IDENT_SYMBOL[k]} {t.lower()}" for k, t, _ in IDENT_GROUPS)
        lay.addWidget(note(legend))
        self.params = _table(0, ["parameter", "unit", "start", "calibrated", "std",
                                 "identifiability"])
        lay.addWidget(self.params)
        lay.addWidget(note("Lengths in mm, angles in degrees (the parameter file keeps m and "
                           "rad); u is the actuator unit of qm, the drives' position unit "
                           "(the station config's increments_per_unit)."))
        lay.addWidget(heading("Validation on held-out poses"))
        self.validation = _table(0, ["channel", "poses", "RMS before", "RMS after", "change",
                                     "max before", "max after"])
        lay.addWidget(self.validation)
        self.validation_note = note("")    # why a "before" is n/a, a failed validation
        lay.addWidget(self.validation_note)
        self.notes = note("", WARN_COLOR)
        lay.addWidget(self.notes)
        self.outcome = None
        self.units = MM_DEG
        self.clear()

    def clear(self) -> None:
        self.plots.reset()
        self.summary.setText("Not calibrated yet.")
        self.quality.setText("")
        self.strip.clear_result()
        self.strip_heading.setText(STRIP_HEADING)
        self.params.setRowCount(0)
        self.validation.setRowCount(0)
        for t in (self.params, self.validation):
            t.clearSpans()
            t.fit()
        self.validation_note.setText("")
        self.notes.setText("")
        self.outcome = None

    def add_iteration(self, iteration) -> None:
        self.plots.add(iteration)

    def show_outcome(self, outcome, validation=None) -> None:
        from station.gui.widgets import display_units

        self.units = display_units()
        self.outcome = outcome
        res, model = outcome.result, outcome.model
        self.plots.finish(res, outcome.nominal)
        sig = ", ".join(f"{k} {self.units.text(v, channel_si(k), '.3g')}"
                        for k, v in res.sigma.items())
        self.summary.setText(
            f"<b>{html.escape(res.message)}</b> \u2014 {res.n_identifiable} of "
            f"{len(res.names)} parameters identifiable, {model.n_poses} poses, condition "
            f"number at the solution {res.condition_number:.4g}; sigma "
            f"({'from the trace' if res.sigma_known else 'estimated, eq. 51'}): "
            f"{html.escape(sig)}")
        self.summary.setTextFormat(Qt.TextFormat.RichText)
        self.show_quality(outcome.quality)
        self._show_strip(res)
        self._show_params(outcome)
        self.show_validation(validation or [])
        notes = [describe_not_identified(d) for d in not_identified(outcome)]
        notes += list(getattr(model, "notes", ()) or ())
        notes += operator_notes(outcome)
        self.notes.setText("\n".join(f"Note: {n}" for n in notes))

    def show_quality(self, quality) -> None:
        """One line: the fit-quality gate's verdict, outliers left out, what failed."""
        if quality is None:
            self.quality.setText("")
            return
        out = ", ".join(f"pose {o['pose']} {o['channel']}" for o in quality.outliers)
        text = "Fit quality: " + ("passed" if quality.passed else "FAILED: " + quality.summary())
        if out:
            text += f" — outliers left out of the fit: {out}"
        self.quality.setText(text)
        self.quality.setStyleSheet(f"color: {OK_COLOR if quality.passed else BAD_COLOR};")

    def _show_strip(self, res) -> None:
        self.strip_heading.setText(f"{STRIP_HEADING}: {res.method}")
        self.strip.set_result(res.names, res.status)

    def _show_params(self, outcome) -> None:
        res, t = outcome.result, self.params
        units = param_units(outcome.trace)
        groups = [group_of(st) for st in res.status]
        rows = []
        for key, label, expl in IDENT_GROUPS:
            idx = [j for j, g in enumerate(groups) if g == key]
            if idx:
                rows.append((key, label, expl, None))
                rows += [(key, label, expl, j) for j in idx]
        t.clearSpans()
        t.setRowCount(len(rows))
        for r, (key, label, expl, j) in enumerate(rows):
            if j is None:
                item = QTableWidgetItem(f"{IDENT_SYMBOL[key]} {label} "
                                        f"({groups.count(key)}) \u2013 {expl}")
                f = QFont(item.font())
                f.setBold(True)
                item.setFont(f)
                item.setForeground(QColor(GROUP_COLOR[key]))
                _spanned(t, r, item)
                continue
            std = res.std[j] if key == "identifiable" else float("nan")
            si = units.get(res.names[j], "")
            label, f = self.units.unit(si) if si else ("", 1.0)   # mm and degrees
            cells = (res.names[j], label, _num(outcome.nominal[j] * f),
                     _num(res.x[j] * f), _num(std * f, ".3g"), res.status[j].label)
            for c, text in enumerate(cells):
                item = QTableWidgetItem(text)
                if 2 <= c <= 4:
                    item.setTextAlignment(Qt.AlignmentFlag.AlignRight
                                          | Qt.AlignmentFlag.AlignVCenter)
                t.setItem(r, c, item)
        t.fit()

    def show_validation(self, validation) -> None:
        t = self.validation
        t.clearSpans()
        t.setRowCount(len(validation))
        for r, v in enumerate(validation):
            si = v.get("unit", "")

            def f(x, si=si):
                return "n/a" if x is None else self.units.text(x, si)

            rb, ra = v.get("rms_before"), v.get("rms_after")
            change = (f"{(ra / rb - 1) * 100:+.4g} %" if rb not in (None, 0) and ra is not None
                      else "\u2013")
            cells = (v["channel"], str(v.get("n", "")), f(rb), f(ra), change,
                     f(v.get("max_before")), f(v.get("max_after")))
            for c, text in enumerate(cells):
                item = QTableWidgetItem(text)
                if c >= 1:
                    item.setTextAlignment(Qt.AlignmentFlag.AlignRight
                                          | Qt.AlignmentFlag.AlignVCenter)
                if c == 3 and rb is not None and ra is not None:
                    item.setForeground(QColor(OK_COLOR if ra < rb else BAD_COLOR))
                t.setItem(r, c, item)
        if not validation:
            t.setRowCount(1)
            _spanned(t, 0, QTableWidgetItem("no held-out poses in this trace"))
        t.fit()
        # the reasons beside the table, not in a status bar: why a "before" is n/a
        said = []
        for v in validation:
            for key, lead in (("note", "RMS before n/a"), ("error", "validation failed")):
                text = v.get(key)
                if text and (key == "error" or v.get("rms_before") is None):
                    line = f"{v.get('channel')}: {lead}: {text}"
                    if line not in said:
                        said.append(line)
        self.validation_note.setText("\n".join(said))


def validation_rows(outcome) -> list[dict]:
    """Validation errors of an offline outcome (the session's own function)."""
    from station.fitting.validation import validation_errors

    try:
        return validation_errors(outcome)
    except Exception as e:  # noqa: BLE001 - shown, the calibration itself stands
        return [{"channel": "(validation failed)", "n": 0, "rms_before": None,
                 "rms_after": None, "unit": "", "error": str(e)}]


