"""A calibration's result as the report shows it: the live convergence plots,
the identifiability table in the style of the report's Table 3 and the
validation errors before and after (used by the Calibrate and Offline pages)."""
from __future__ import annotations

import html
import math

from PySide6.QtCore import QSize, Qt, QTimer
from PySide6.QtGui import QColor, QFont, QFontMetrics, QPalette
from PySide6.QtWidgets import (QAbstractItemView, QAbstractScrollArea, QApplication,
                               QHeaderView, QSizePolicy, QTableWidget, QTableWidgetItem,
                               QVBoxLayout, QWidget)

from station.outputs.fit_summary import describe_not_identified, not_identified, operator_notes
from station.gui.plots import ConvergencePlots
from station.gui.widgets import BAD_COLOR, OK_COLOR, WARN_COLOR, heading, note
from station.outputs.report_context import IDENT_GROUPS, IDENT_SYMBOL, group_of
from station.outputs.units import param_units
from station.outputs.units import MM_DEG, channel_si

STRIP_HEADING = "Identifiability (report Table 3)"
GROUP_COLOR = {"identifiable": OK_COLOR, "no-influence": "#555555", "influence": BAD_COLOR,
               "fixed": "#1f4e9c"}


def _num(v, fmt=".7g") -> str:
    try:
        v = float(v)
    except (TypeError, ValueError):
        return "\u2013"
    return format(v, fmt) if math.isfinite(v) else "\u2013"


#: the identifiability strip's columns at most (one a parameter): more are wrapped into
#: further rows, fewer where the width is short
MAX_STRIP_COLUMNS = 15
STRIP_DEFAULT_WIDTH = 1000     # px: the width assumed before the strip is laid out


def _table(rows: int, headers) -> QTableWidget:
    t = ContentTable(rows, len(headers))
    t.setHorizontalHeaderLabels(list(headers))
    t.verticalHeader().setVisible(False)
    t.setEditTriggers(QTableWidget.EditTrigger.NoEditTriggers)
    t.setSelectionBehavior(QTableWidget.SelectionBehavior.SelectRows)
    t.horizontalHeader().setSectionResizeMode(QHeaderView.ResizeMode.ResizeToContents)
    t.horizontalHeader().setStretchLastSection(True)
    return t


def _wheel_to_page(widget, event) -> None:
    """The wheel over a table that does not scroll scrolls the page it is on (handed to
    the nearest scroll area around it, as the plots do)."""
    w = widget.parentWidget()
    while w is not None and not isinstance(w, QAbstractScrollArea):
        w = w.parentWidget()
    if w is None:
        event.ignore()
        return
    QApplication.sendEvent(w.viewport(), event)


def _no_scrolling(t: QTableWidget) -> None:
    """A table on a page that scrolls: never a scroll bar of its own (it is made as tall
    as its rows and at least as wide as its columns: the page scrolls, not the table)."""
    t.setVerticalScrollBarPolicy(Qt.ScrollBarPolicy.ScrollBarAlwaysOff)
    t.setHorizontalScrollBarPolicy(Qt.ScrollBarPolicy.ScrollBarAlwaysOff)
    t.setSizePolicy(QSizePolicy.Policy.Expanding, QSizePolicy.Policy.Fixed)


def _spanned(t: QTableWidget, r: int, item: QTableWidgetItem) -> None:
    """``item`` across the whole row ``r``, its text wrapped at the table's width
    (:meth:`ContentTable.fit`), not widening the first column (a column is sized to
    its cells' size hints)."""
    item.setData(Qt.ItemDataRole.SizeHintRole, QSize(1, QFontMetrics(item.font()).height()))
    t.setItem(r, 0, item)
    t.setSpan(r, 0, 1, t.columnCount())


class ContentTable(QTableWidget):
    """A table of the results on a page that scrolls (nested scrolling was a table's
    scroll bars inside the page's): as tall as its rows and at least as wide as its
    columns, never a scroll bar of its own; a text across a whole row (a group's
    heading) wraps at the table's width. :meth:`fit` after filling it."""

    def __init__(self, rows: int, columns: int, parent=None):
        super().__init__(rows, columns, parent)
        _no_scrolling(self)
        self.setWordWrap(True)
        self._fitted_width = None

    def _spans(self) -> list[int]:
        return [r for r in range(self.rowCount()) if self.columnSpan(r, 0) > 1]

    def fit(self) -> None:
        """As tall as the rows, at least as wide as the columns (their contents)."""
        header = self.horizontalHeader()
        frame = 2 * self.frameWidth()
        hidden = header.isHidden()
        columns = [max(0 if hidden else header.sectionSizeHint(c), self.sizeHintForColumn(c))
                   for c in range(self.columnCount())]
        vh = self.verticalHeader()
        lead = 0 if vh.isHidden() else vh.sizeHint().width()
        self.setMinimumWidth(frame + lead + sum(columns))
        width = max(self.viewport().width(), sum(columns))
        for r in self._spans():                 # wrapped at the width the row has
            item = self.item(r, 0)
            if item is not None:
                fm = QFontMetrics(item.font().resolve(self.font()))   # as it is drawn
                h = fm.boundingRect(0, 0, max(40, width - 24), 100000,
                                    int(Qt.TextFlag.TextWordWrap), item.text()).height()
                item.setData(Qt.ItemDataRole.SizeHintRole, QSize(1, h + 8))
        self.resizeRowsToContents()
        h = frame + sum(self.rowHeight(r) for r in range(self.rowCount()))
        if not hidden:
            h += max(header.height(), header.sizeHint().height())
        self.setFixedHeight(h)
        self._fitted_width = self.viewport().width()

    def wheelEvent(self, event) -> None:
        _wheel_to_page(self, event)

    def resizeEvent(self, event) -> None:
        super().resizeEvent(event)
        if self._spans() and self.viewport().width() != self._fitted_width:
            QTimer.singleShot(0, self, self.fit)


class IdentifiabilityStrip(QTableWidget):
    """Report Table 3 as a strip: each parameter's name over its identifiability symbol,
    wrapped into rows of at most :data:`MAX_STRIP_COLUMNS` parameters, as many as fit in
    the width it has (a robot file's arm has some 45 parameters: in one row, at 1366 px,
    most were off to the side). As tall as its rows; no scroll bar of its own."""

    def __init__(self, parent=None):
        super().__init__(0, 0, parent)
        self.horizontalHeader().setVisible(False)
        self.verticalHeader().setVisible(False)
        self.horizontalHeader().setSectionResizeMode(QHeaderView.ResizeMode.Fixed)
        self.horizontalHeader().setMinimumSectionSize(8)
        self.setEditTriggers(QTableWidget.EditTrigger.NoEditTriggers)
        self.setSelectionMode(QAbstractItemView.SelectionMode.NoSelection)
        self.setFocusPolicy(Qt.FocusPolicy.NoFocus)
        _no_scrolling(self)
        self.names: list[str] = []
        self._symbols: list[str] = []
        self._status: list = []
        self.columns = 0                 # parameters a row now

    @property
    def symbol_font(self) -> QFont:
        f = QFont(self.font())
        f.setPointSizeF(f.pointSizeF() * 1.3)
        return f

    # -- what it shows --------------------------------------------------------------------------
    def set_result(self, names, status) -> None:
        """Each parameter of ``names`` with its identifiability ``status``."""
        self.names = list(names)
        self._status = list(status)
        self._symbols = [IDENT_SYMBOL[group_of(st)] for st in self._status]
        self._arrange()

    def clear_result(self) -> None:
        self.names, self._symbols, self._status, self.columns = [], [], [], 0
        self.setRowCount(0)
        self.setColumnCount(0)
        self.setFixedHeight(2 * self.frameWidth())

    def symbols(self) -> dict[str, str]:
        """Parameter name -> the symbol shown under it (from the cells)."""
        out = {}
        for r in range(0, self.rowCount(), 2):
            for c in range(self.columnCount()):
                name, sym = self.item(r, c), self.item(r + 1, c)
                if name is not None and sym is not None:
                    out[name.text()] = sym.text()
        return out

    # -- layout ---------------------------------------------------------------------------------
    def _widths(self) -> list[int]:
        """Each parameter's cell width: its name or its symbol, with the cell's margins."""
        names, syms = QFontMetrics(self.font()), QFontMetrics(self.symbol_font)
        return [max(names.horizontalAdvance(n), syms.horizontalAdvance(s)) + 12
                for n, s in zip(self.names, self._symbols)]

    def _column_widths(self, widths: list[int], columns: int) -> list[int]:
        return [max(widths[k] for k in range(c, len(widths), columns)) for c in range(columns)]

    def columns_for(self, width: float) -> int:
        """Parameters a row: the fewest rows, each at most :data:`MAX_STRIP_COLUMNS`
        parameters and as even as can be (16 in two rows of 8, not 15 and 1), whose
        columns fit in ``width`` pixels; one a row if none do."""
        widths = self._widths()
        n = len(widths)
        if not n:
            return 0
        for rows in range(math.ceil(n / MAX_STRIP_COLUMNS), n + 1):
            cols = math.ceil(n / rows)
            if sum(self._column_widths(widths, cols)) <= width:
                return cols
        return 1

    def _available(self) -> float:
        if not self.isVisible() or self.width() < 50:
            return STRIP_DEFAULT_WIDTH
        return self.width() - 2 * self.frameWidth()

    def _arrange(self) -> None:
        n = len(self.names)
        cols = self.columns_for(self._available())
        rows = math.ceil(n / cols) if n else 0
        self.columns = cols
        self.clearContents()
        self.setColumnCount(cols)
        self.setRowCount(2 * rows)
        band = self.palette().color(QPalette.ColorRole.Button)
        for k, (name, sym, st) in enumerate(zip(self.names, self._symbols, self._status)):
            r, c = 2 * (k // cols), k % cols
            head = QTableWidgetItem(name)
            head.setTextAlignment(Qt.AlignmentFlag.AlignCenter)
            head.setBackground(band)
            head.setToolTip(f"{name}: {st.label}")
            self.setItem(r, c, head)
            g = group_of(st)
            item = QTableWidgetItem(sym)
            item.setTextAlignment(Qt.AlignmentFlag.AlignCenter)
            item.setForeground(QColor(GROUP_COLOR[g]))
            item.setFont(self.symbol_font)
            item.setToolTip(f"{name}: {st.label}")
            self.setItem(r + 1, c, item)
        for c, w in enumerate(self._column_widths(self._widths(), cols) if n else []):
            self.setColumnWidth(c, w)
        self.resizeRowsToContents()
        self.setFixedHeight(2 * self.frameWidth() + sum(self.rowHeight(r)
                                                        for r in range(self.rowCount())))
        # never wider than one parameter needs: narrower, it wraps into more rows
        self.setMinimumWidth(2 * self.frameWidth() + (max(self._widths()) if n else 0))

    def wheelEvent(self, event) -> None:
        _wheel_to_page(self, event)

    def resizeEvent(self, event) -> None:
        super().resizeEvent(event)
        if self.names and self.columns_for(self._available()) != self.columns:
            QTimer.singleShot(0, self, self._rearrange)

    def showEvent(self, event) -> None:
        super().showEvent(event)
        if self.names and self.columns_for(self._available()) != self.columns:
            QTimer.singleShot(0, self, self._rearrange)

    def _rearrange(self) -> None:
        if self.names and self.columns_for(self._available()) != self.columns:
            self._arrange()


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


