"""Small widgets the pages share: live readings, device status, headings."""
from __future__ import annotations

import math

from PySide6.QtCore import Qt
from PySide6.QtGui import QColor, QFont
from PySide6.QtWidgets import (QFrame, QGridLayout, QHeaderView, QLabel, QScrollArea,
                               QSizePolicy, QTableWidget, QTableWidgetItem, QWidget)

from station.outputs.units import MM_DEG, channel_si, target_coords  # noqa: F401 (re-exported)

OK_COLOR, BAD_COLOR, WARN_COLOR = "#1b7a2f", "#b3261e", "#8a5a00"


# decimals of a live reading per display unit
DECIMALS = {"mm": 3, "cm": 4, "m": 6, "\u00b5m": 1, "\u00b0": 3, "rad": 5, "mrad": 2, "u": 3}


_UNITS = [MM_DEG]      # the wizard's display units (the station config's [display])


def set_units(units) -> None:
    """The display units of every reading shown from now on."""
    _UNITS[0] = units


def display_units():
    return _UNITS[0]


def fixed(v: float, decimals: int) -> str:
    """``v`` with ``decimals`` decimals, never ``-0.000`` (a value that rounds to zero
    is shown as ``0.000``)."""
    text = f"{v:.{decimals}f}"
    return text.lstrip("-") if float(text) == 0 else text


def channel_text(channel: str, value: float, units=None) -> tuple[str, str]:
    """A reading as the operator reads it: ``(value, unit)`` in the display units
    (:mod:`station.outputs.units`: distance in mm, angles in degrees by default; actuator
    values in actuator units, u)."""
    if value is None or not isinstance(value, (int, float)) or not math.isfinite(value):
        return "\u2013", ""
    label, factor = (units or _UNITS[0]).unit(channel_si(channel) or "u")
    return fixed(value * factor, DECIMALS.get(label, 4)), label


def is_marker(channel: str) -> bool:
    """Whether ``channel`` is a coordinate of a point on the tool (``m1_x``: the motion
    capture's, m in its frame; NaN where it does not see the point)."""
    return channel_si(channel) == "m" and channel[:1] == "m" and channel[-2:-1] == "_"


def marker_channels(count: int) -> tuple[str, ...]:
    """``m1_x, m1_y, m1_z, ... mM_z``: the motion capture's channels of ``count`` points."""
    return tuple(f"m{k}_{a}" for k in range(1, count + 1) for a in "xyz")


def markers_text(values: dict, labels=(), units=None) -> str:
    """The points on the tool read now, for people: ``m1 tool1 (x, y, z) mm; m2 tool2 not
    seen`` in the display units (a point not seen is said so: not an error)."""
    u = units or _UNITS[0]
    unit, _ = u.unit("m")
    out, k = [], 1
    while f"m{k}_x" in values:
        xyz = [values.get(f"m{k}_{a}") for a in "xyz"]
        name = f"m{k}" + (f" {labels[k - 1]}" if k <= len(labels) else "")
        if any(v is None or not math.isfinite(v) for v in xyz):
            out.append(f"{name} not seen")
        else:
            out.append(f"{name} (" + ", ".join(u.number(v, "m", ".5g") for v in xyz)
                       + f") {unit}")
        k += 1
    return "; ".join(out)


def channel_label(channel: str) -> str:
    return {"tilt": "tilt (last link)", "distance": "distance (draw-wire)"}.get(channel, channel)


def heading(text: str) -> QLabel:
    lab = QLabel(text)
    f = lab.font()
    f.setBold(True)
    f.setPointSizeF(f.pointSizeF() * 1.15)
    lab.setFont(f)
    return lab


def note(text: str, color: str | None = None) -> QLabel:
    lab = QLabel(text)
    lab.setWordWrap(True)
    lab.setTextInteractionFlags(Qt.TextInteractionFlag.TextSelectableByMouse)
    if color:
        lab.setStyleSheet(f"color: {color};")
    return lab


def scrolled(widget: QWidget) -> QScrollArea:
    area = QScrollArea()
    area.setWidgetResizable(True)
    area.setFrameShape(QFrame.Shape.NoFrame)
    area.setWidget(widget)
    return area


class ReadingsPanel(QFrame):
    """Channel -> value in large type, updated live (``set_values``).

    channels: the channels to show, in order (others are added as they come).
    marker_grid: a point on the tool (``m1_x, m1_y, m1_z``) in one row, its x, y, z side
    by side under a header (where nine rows of them would not fit).
    """

    def __init__(self, channels=(), large: bool = True, parent=None,
                 marker_grid: bool = False):
        super().__init__(parent)
        self.setFrameShape(QFrame.Shape.StyledPanel)
        self._grid = QGridLayout(self)
        self._grid.setHorizontalSpacing(12)
        self._rows: dict[str, tuple[QLabel, QLabel]] = {}
        self._large = large
        self._marker_grid = marker_grid
        self._marker_rows: dict[str, tuple[int, QLabel]] = {}    # "m1" -> (row, its name)
        self._next = 0                                            # the next free row
        self.values: dict[str, float] = {}
        for ch in channels:
            self._row(ch)

    def _value_label(self, ch: str) -> QLabel:
        value = QLabel("\u2013")
        value.setAlignment(Qt.AlignmentFlag.AlignRight | Qt.AlignmentFlag.AlignVCenter)
        value.setTextInteractionFlags(Qt.TextInteractionFlag.TextSelectableByMouse)
        value.setAccessibleName(f"{ch} reading")
        # the motion capture's 3 coordinates a point: in the label's size (15 rows of
        # an arm with 3 markers in sight at 1366x768 less a taskbar and a title bar)
        if self._large and not is_marker(ch):
            f = QFont(value.font())
            f.setPointSizeF(f.pointSizeF() * 1.5)
            f.setFamily("DejaVu Sans Mono")
            value.setFont(f)
        value.setMinimumWidth(80 if self._marker_grid and is_marker(ch) else 120)
        return value

    def _row(self, ch: str):
        if ch in self._rows:
            return self._rows[ch]
        value = self._value_label(ch)
        if self._marker_grid and is_marker(ch):
            point = ch[:-2]
            if not self._marker_rows:       # the header of the points' coordinates
                for c, axis in enumerate("xyz", start=1):
                    head = QLabel(axis)
                    head.setAlignment(Qt.AlignmentFlag.AlignRight)
                    self._grid.addWidget(head, self._next, c)
                self._next += 1
            if point not in self._marker_rows:
                name = QLabel(point)
                self._grid.addWidget(name, self._next, 0)
                self._marker_rows[point] = (self._next, name)
                self._next += 1
            r, name = self._marker_rows[point]
            self._grid.addWidget(value, r, 1 + "xyz".index(ch[-1]))
        else:
            name = QLabel(channel_label(ch))
            self._grid.addWidget(name, self._next, 0)
            self._grid.addWidget(value, self._next, 1)
            self._next += 1
        self._rows[ch] = (name, value)
        return self._rows[ch]

    def set_channels(self, channels) -> None:
        for ch in channels:
            self._row(ch)

    def set_values(self, values: dict) -> None:
        for ch, v in values.items():
            if ch in self._rows or not self._rows:
                self.values[ch] = v
                text, unit = channel_text(ch, v)
                if is_marker(ch) and text == "\u2013" and v is not None:
                    # the motion capture's NaN: no fault; said once a point in the grid
                    text, unit = ("" if self._marker_grid and ch[-1] != "x" else "not seen"), ""
                self._row(ch)[1].setText(f"{text} {unit}".strip())

    def text_of(self, ch: str) -> str:
        return self._rows[ch][1].text() if ch in self._rows else ""


class DeviceTable(QTableWidget):
    """One row per device: name, state, its readings or what is wrong and what to do."""

    def __init__(self, parent=None):
        super().__init__(0, 3, parent)
        self.setHorizontalHeaderLabels(["device", "state", "readings / what to do"])
        self.verticalHeader().setVisible(False)
        self.setEditTriggers(QTableWidget.EditTrigger.NoEditTriggers)
        self.setWordWrap(True)
        h = self.horizontalHeader()
        h.setSectionResizeMode(0, QHeaderView.ResizeMode.ResizeToContents)
        h.setSectionResizeMode(1, QHeaderView.ResizeMode.ResizeToContents)
        h.setSectionResizeMode(2, QHeaderView.ResizeMode.Stretch)
        self.setSizePolicy(QSizePolicy.Policy.Expanding, QSizePolicy.Policy.Preferred)
        self.setMinimumHeight(120)
        self.states: dict[str, bool] = {}

    def set_devices(self, readings) -> None:
        """``readings``: list of :class:`station.gui.worker.DeviceReading`."""
        self.setRowCount(len(readings))
        for r, dev in enumerate(readings):
            self.states[dev.name] = dev.ok
            state = QTableWidgetItem("\u2713 OK" if dev.ok else "\u2717 fault")
            state.setForeground(QColor(OK_COLOR if dev.ok else BAD_COLOR))
            if dev.ok and any(is_marker(ch) for ch in dev.values):    # the motion capture
                text = markers_text(dev.values, getattr(dev, "labels", ()))
            else:
                text = (", ".join(f"{ch} {' '.join(channel_text(ch, v))}"
                                  for ch, v in dev.values.items()) if dev.ok else dev.text)
            for c, item in enumerate((QTableWidgetItem(dev.name), state, QTableWidgetItem(text))):
                item.setToolTip(text)
                self.setItem(r, c, item)
        self.resizeRowsToContents()
        self._fit()

    def _fit(self) -> None:
        """As tall as its rows (at least 120 px): no empty area pushing the page down."""
        h = self.horizontalHeader().height() + sum(self.rowHeight(r)
                                                   for r in range(self.rowCount()))
        self.setMaximumHeight(max(120, h + 2 * self.frameWidth() + 4))

    def clear_devices(self) -> None:
        self.setRowCount(0)
        self.states = {}


def wheel_to_page(widget, event) -> None:
    """The wheel over a widget that does not scroll (a plot, a table sized to its rows)
    scrolls the page it is on: handed to the nearest scroll area around it."""
    from PySide6.QtWidgets import QAbstractScrollArea, QApplication

    w = widget.parentWidget()
    while w is not None and not isinstance(w, QAbstractScrollArea):
        w = w.parentWidget()
    if w is None:
        event.ignore()
        return
    QApplication.sendEvent(w.viewport(), event)
