"""The arm of a robot file in 3D on the Qt canvas: :class:`ArmFigure` is the reference
page's live picture for a robot file: the arm at the encoders read now
(:mod:`station.gui.arm_drawing` draws it), the reference mark, the draw-wire's anchor and
its wire to the tool, the tool's inclinometer (its axes and the roll and pitch read now)
and the steps (:class:`station.gui.pictures.ReferenceSteps`).

Lengths are drawn in the display units (:func:`station.gui.widgets.display_units`).
"""
from __future__ import annotations

import math

import numpy as np
from PySide6.QtCore import QTimer
from PySide6.QtWidgets import QLabel, QVBoxLayout, QWidget

from station.gui.arm_drawing import draw_arm, draw_floor, setup_axes, stick, view_box
from station.gui.pictures import BAD, CABLE, INK, TARGET, ReferenceSteps
from station.gui.plots import Canvas
from station.outputs.units import MM_DEG

INCL_AXIS = 0.12          # m: length of the inclinometer's drawn axes
MIN_WIDTH, MIN_HEIGHT = 380, 300     # px: the 3D view (and its size hint)
REDRAW_MS = 120           # coalesced redraws (the polling delivers readings every 0.4 s)


class ArmFigure(ReferenceSteps, QWidget):
    """The reference page's live 3D picture of a robot file's arm (module docstring):
    ``set_state`` with the actuators read, :meth:`set_tilt` with the inclinometer's."""

    def __init__(self, robot, nominal, parent=None, target_label: str = "reference point",
                 units=MM_DEG, home_qm=None):
        QWidget.__init__(self, parent)
        self._init_steps(robot, nominal, target_label, units)
        self.roll = self.pitch = None
        # asks for its minimum: on the reference page it fills the room beside the jog
        # panel, and the buttons under it stay in sight at 1366 x 768 (at matplotlib's
        # 614 x 460 the page was laid out taller than the window, the buttons cut)
        self.canvas = Canvas(MIN_HEIGHT, hint=(MIN_WIDTH, MIN_HEIGHT))
        self.steps_label = QLabel()
        self.steps_label.setWordWrap(True)
        lay = QVBoxLayout(self)
        lay.setContentsMargins(0, 0, 0, 0)
        lay.addWidget(self.canvas, 1)
        lay.addWidget(self.steps_label)
        self.setMinimumSize(MIN_WIDTH, MIN_HEIGHT)
        self.ax = self.canvas.figure.add_subplot(projection="3d")
        self.ax.view_init(elev=22, azim=-60)
        self._box = None
        self._home = home_qm
        self.draws = 0
        self._pending = False
        self._drawn_key = None
        self._changed()

    def set_tilt(self, roll, pitch) -> None:
        """The inclinometer's roll and pitch read now (rad)."""
        self.roll, self.pitch = roll, pitch
        self._changed()

    def _changed(self) -> None:
        self._steps_text()
        if not self._pending:
            self._pending = True
            QTimer.singleShot(REDRAW_MS, self._draw)

    def _steps_text(self) -> None:
        rows = []
        for i, text in enumerate(self.steps):
            mark = "!" if i in self.warned else "\u2713" if i in self.done else f"{i + 1}."
            color = BAD if i in self.warned else "#777" if i in self.done else INK
            line = f"{mark} {text}"
            if i == self.step:
                line = f"<b>{line}</b>"
            rows.append(f'<span style="color:{color}">{line}</span>')
        self.steps_label.setText("<br>".join(rows))

    def _key(self):
        def r(v):
            return None if v is None else tuple(np.round(np.asarray(v, dtype=float), 5))
        return (r(self.qm), r(self.target_qm), r(self.captured_qm), self.captured, self.step,
                None if self.roll is None else round(self.roll, 4),
                None if self.pitch is None else round(self.pitch, 4))

    def _draw(self) -> None:
        self._pending = False
        key = self._key()
        if key == self._drawn_key:
            return
        self._drawn_key = key
        self.draws += 1
        from station.gui.widgets import display_units

        unit, scale = display_units().unit("m")
        ax = self.ax
        elev, azim = ax.elev, ax.azim
        ax.cla()
        ax.view_init(elev=elev, azim=azim)
        pose = next((q for q in (self.qm, self.target_qm, self._home) if q is not None), None)
        if pose is None:
            ax.text2D(0.5, 0.5, "waiting for the encoders", ha="center", transform=ax.transAxes,
                      color="#777", fontsize=8)
            self.canvas.draw_idle()
            return
        if self._box is None:
            self._box = view_box(self.robot, self.xi, pose)
        lo, hi = self._box
        draw_floor(ax, lo, hi, scale)
        target = anchor = None
        if self.target_qm is not None:
            target = stick(self.robot, self.target_qm, self.xi).tool[:3, 3]
            t = target * scale
            ax.scatter([t[0]], [t[1]], [t[2]], marker="o", s=110, facecolors="none",
                       edgecolors=TARGET, linewidths=1.8, depthshade=False)
            ax.text(t[0], t[1], t[2], f"  {self.target_label}", color=TARGET, fontsize=7)
        if self.captured and self.captured_qm is not None:
            anchor = stick(self.robot, self.captured_qm, self.xi).tool[:3, 3]
        elif self.step == 1:
            anchor = target
        if self.qm is not None:
            s = stick(self.robot, self.qm, self.xi)
            draw_arm(ax, s, scale)
            tool = s.tool[:3, 3]
            if anchor is not None:          # the draw-wire: its body at the anchor, the wire
                a, b = anchor * scale, tool * scale
                ax.scatter([a[0]], [a[1]], [a[2]], marker="s", s=60, color=CABLE,
                           depthshade=False)
                ax.text(a[0], a[1], a[2], "draw-wire  ", color=CABLE, fontsize=7,
                        ha="right", va="top")
                ax.plot([a[0], b[0]], [a[1], b[1]], [a[2], b[2]], color=CABLE, lw=1.6,
                        ls="-" if self.captured else "--")
            elif target is not None:        # the way to the mark
                a, b = tool * scale, target * scale
                ax.plot([a[0], b[0]], [a[1], b[1]], [a[2], b[2]], color=TARGET, lw=1.0,
                        ls="--")
            self._inclinometer(ax, s.tool, scale)
        setup_axes(ax, lo, hi, scale, unit)
        head = self.headline()
        lines = [head] if head else []
        if self.roll is not None and self.pitch is not None:
            lines.append((f"inclinometer on the tool: roll {math.degrees(self.roll):+.2f}\u00b0, "
                          f"pitch {math.degrees(self.pitch):+.2f}\u00b0", "#555"))
        for k, (text, color) in enumerate(lines):
            ax.text2D(0.0, 1.0 - 0.06 * k, text, transform=ax.transAxes, fontsize=8,
                      color=color, va="top")
        self.canvas.draw_idle()

    def _inclinometer(self, ax, T, scale: float) -> None:
        """The inclinometer on the tool: its x (red) and y (green) axes, as mounted
        nominally (along the tool frame's)."""
        o = T[:3, 3]
        for col, color in ((0, "#d62728"), (1, "#2ca02c")):
            e = (o + INCL_AXIS * T[:3, col]) * scale
            a = o * scale
            ax.plot([a[0], e[0]], [a[1], e[1]], [a[2], e[2]], color=color, lw=2.0)
        e = (o + INCL_AXIS * T[:3, 0]) * scale
        ax.text(e[0], e[1], e[2], " inclinometer", color="#555", fontsize=7)
