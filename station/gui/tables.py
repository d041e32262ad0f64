"""The tables of a calibration's result (:mod:`station.gui.results`): tables as tall and
wide as their content, so that the page scrolls and not each table (a wheel over one
scrolls the page), and the identifiability strip, report Table 3 in rows of named
symbols."""
from __future__ import annotations

import math

from PySide6.QtCore import QSize, Qt, QTimer
from PySide6.QtGui import QColor, QFont, QFontMetrics, QPalette
from PySide6.QtWidgets import (QAbstractItemView, QHeaderView, QSizePolicy, QTableWidget, QTableWidgetItem)

from station.gui.widgets import BAD_COLOR, OK_COLOR, wheel_to_page
from station.outputs.report_context import IDENT_SYMBOL, group_of

GROUP_COLOR = {"identifiable": OK_COLOR, "no-influence": "#555555", "influence": BAD_COLOR,
               "fixed": "#1f4e9c"}


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
        wheel_to_page(self, event)

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
        wheel_to_page(self, event)

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
