"""The wrist's reference picture: the platform with the inclinometer on it and a bubble
level of the roll and pitch read now against the mounting tolerance (QPainter, from the
live readings; the arm's picture and the shared drawing helpers:
:mod:`station.gui.pictures`)."""
from __future__ import annotations

import math

from PySide6.QtCore import QPointF, QRectF, Qt
from PySide6.QtGui import QBrush, QColor, QPainter, QPainterPath, QPen

from station.gui.pictures import (BAD, INK, MOUNT_TOLERANCE, OK, READING_TEMPLATE, TARGET,
                                  _Picture, draw_wrapped, text_height)


class LevelPicture(_Picture):
    """The wrist's inclinometer mounting check: roll and pitch now, as a bubble level."""

    def __init__(self, parent=None):
        super().__init__(parent)
        self.roll = self.pitch = None
        self.steps = [("Mount the inclinometer flat on the platform, its x axis (arrow) "
                       "along the platform's x axis."),
                      ("At the home pose roll and pitch must read near 0: the bubble inside "
                       "the green circle.")]

    @property
    def level(self) -> bool | None:
        if self.roll is None or self.pitch is None:
            return None
        return abs(self.roll) <= MOUNT_TOLERANCE and abs(self.pitch) <= MOUNT_TOLERANCE

    def set_angles(self, roll, pitch) -> None:
        self.roll, self.pitch = roll, pitch
        self.step = 1 if self.level else 0
        self.done = {0} if self.level else set()
        self.update()

    def reading_text(self) -> str | None:
        """The line under the pictures: roll and pitch now and whether that is level."""
        if self.roll is None or self.pitch is None:
            return None
        return (f"roll {math.degrees(self.roll):+.2f}\u00b0, pitch "
                f"{math.degrees(self.pitch):+.2f}\u00b0 \u2014 "
                + ("level: mounted flat" if self.level else "not level: check the mount"))

    def paintEvent(self, _event) -> None:
        p = QPainter(self)
        p.setRenderHint(QPainter.RenderHint.Antialiasing)
        w, h = self.width(), self.height()
        p.fillRect(self.rect(), QColor("#fbfbfb"))
        font = self.font()
        # from the top: the two captions, the platform beside the bubble level, the
        # reading, the steps; every text measured first, so none is cut at the edge
        steps_h = self._steps_height(w - 20)
        bottom = h - (steps_h + 8 if steps_h else 0) - 6
        reading = self.reading_text()
        read_h = max(text_height(font, w - 20, reading or ""),
                     text_height(font, w - 20, READING_TEMPLATE))
        half = w * 0.5
        captions = ("platform (side view, tilt \u00d75)",
                    f"bubble level (green circle: \u00b1{math.degrees(MOUNT_TOLERANCE):.0f}\u00b0)")
        cap_h = max(text_height(font, half - 20, t) for t in captions)
        top = 10 + cap_h + 6
        panel_bottom = bottom - read_h - 8
        left = QRectF(10, top, half - 20, max(20.0, panel_bottom - top))
        right = QRectF(half + 10, top, half - 20, max(20.0, panel_bottom - top))
        c = left.center()
        pitch = self.pitch or 0.0
        p.save()
        p.translate(c)
        p.rotate(-math.degrees(pitch) * 5)          # exaggerated, as a hint
        p.setPen(QPen(QColor(INK), 1.5))
        p.setBrush(QBrush(QColor("#cfd8dc")))
        half_len = min(left.width() * 0.4, left.height() * 0.4)
        p.drawRect(QRectF(-half_len, 0, 2 * half_len, 14))
        p.setBrush(QBrush(QColor("#ffcc80")))
        p.drawRect(QRectF(-30, -26, 60, 26))
        p.drawText(QRectF(-30, -26, 60, 26), Qt.AlignmentFlag.AlignCenter, "incl.")
        p.setPen(QPen(QColor(TARGET), 2))
        p.drawLine(QPointF(-20, -36), QPointF(40, -36))
        path = QPainterPath(QPointF(40, -36))
        path.lineTo(32, -41)
        path.lineTo(32, -31)
        path.closeSubpath()
        p.fillPath(path, QColor(TARGET))
        p.drawText(QPointF(44, -32), "x")
        p.restore()
        p.setPen(QColor(INK))
        draw_wrapped(p, QRectF(10, 10, half - 20, cap_h), captions[0])
        draw_wrapped(p, QRectF(half + 10, 10, half - 20, cap_h), captions[1])
        rc = right.center()
        R = min(right.width(), right.height()) * 0.4
        p.setPen(QPen(QColor("#999"), 1))
        p.setBrush(Qt.BrushStyle.NoBrush)
        p.drawEllipse(rc, R, R)
        p.drawLine(rc - QPointF(R, 0), rc + QPointF(R, 0))
        p.drawLine(rc - QPointF(0, R), rc + QPointF(0, R))
        p.setPen(QPen(QColor(OK), 2))
        p.drawEllipse(rc, R / 2, R / 2)
        if reading is not None:
            scale = (R / 2) / MOUNT_TOLERANCE
            off = QPointF(max(-R, min(R, self.roll * scale)), max(-R, min(R, -self.pitch * scale)))
            p.setBrush(QBrush(QColor(OK if self.level else BAD)))
            p.setPen(Qt.PenStyle.NoPen)
            p.drawEllipse(rc + off, 9, 9)
            p.setPen(QColor(OK if self.level else BAD))
            draw_wrapped(p, QRectF(10, bottom - read_h, w - 20, read_h), reading)
        self._steps(p, QRectF(10, h - steps_h - 6, w - 20, steps_h))
        p.end()
