"""Pictures of what to do at the reference step, drawn with QPainter from the
live readings (no image files).

* :class:`ArmPicture` (serial arm): a side view of the arm in its vertical
  plane at the actuator values read now (nominal model), the point to bring
  the end effector to, the draw-wire cable (attached once captured), and the
  rail with the carriage; the steps, the current one in bold.
* :class:`LevelPicture` (wrist): the platform with the inclinometer on it and a
  bubble level of the roll and pitch read now against the mounting tolerance.
"""
from __future__ import annotations

import itertools
import math

import numpy as np
from PySide6.QtCore import QPointF, QRectF, Qt
from PySide6.QtGui import QBrush, QColor, QFont, QPainter, QPainterPath, QPen
from PySide6.QtWidgets import QSizePolicy, QWidget

from station.outputs.units import MM_DEG

INK, ARM, TARGET, CABLE, OK, BAD = ("#202124", "#3c6e9f", "#d35400", "#6a1b9a", "#1b7a2f",
                                     "#b3261e")
NEAR_M = 0.01            # end effector this close to the target counts as there (m, nominal)
FAR_M = 0.05             # a reference captured farther from the mark is warned about (m)
MOUNT_TOLERANCE = math.radians(2.0)


class _Picture(QWidget):
    def __init__(self, parent=None):
        super().__init__(parent)
        self.setMinimumSize(380, 280)
        self.setSizePolicy(QSizePolicy.Policy.Expanding, QSizePolicy.Policy.Expanding)
        self.steps: list[str] = []
        self.step = 0                  # the current step (bold)
        self.done: set[int] = set()    # the steps ticked
        self.warned: set[int] = set()  # steps marked as not done as asked

    def _steps(self, p: QPainter, rect: QRectF) -> None:
        f = QFont(self.font())
        y = rect.top()
        for i, text in enumerate(self.steps):
            f.setBold(i == self.step)
            p.setFont(f)
            p.setPen(QColor(BAD if i in self.warned else "#777" if i in self.done else INK))
            mark = "!" if i in self.warned else "\u2713" if i in self.done else f"{i + 1}."
            r = QRectF(rect.left(), y, rect.width(), 200)
            br = p.boundingRect(r, Qt.TextFlag.TextWordWrap, f"{mark} {text}")
            p.drawText(r, Qt.TextFlag.TextWordWrap, f"{mark} {text}")
            y += br.height() + 4


class ReferenceSteps:
    """What the reference step's pictures of an arm share: the steps to the reference
    and where the arm is on them, from the model's tool position. ``set_state`` with
    the readings; :meth:`_changed` repaints."""

    STEPS = [("Jog the end effector to the orange mark (or use \u2018Go to the "
              "suggested point\u2019)."),
             "Attach the draw-wire cable's end to the end effector there.",
             ("Press Capture: the draw-wire is zeroed and the actuator values "
              "recorded.")]

    def _init_steps(self, robot, nominal, target_label: str, units) -> None:
        self.robot, self.xi = robot, np.asarray(nominal, dtype=float)
        self.target_label = target_label
        self.qm = None
        self.target_qm = None
        self.captured = False
        self.captured_qm = None
        self.capture_offset = None
        self.distance_to_target = None
        self.units = units
        self.steps = list(self.STEPS)
        self.step, self.done, self.warned = 0, set(), set()

    def _distance(self, qm) -> float | None:
        if qm is None or self.target_qm is None:
            return None
        a = self.robot.fk(qm, self.xi)[0, :3]
        b = self.robot.fk(self.target_qm, self.xi)[0, :3]
        return float(np.linalg.norm(a - b))

    def set_state(self, qm=None, target_qm=None, captured=None, captured_qm=None) -> None:
        """The arm now (``qm``), the suggested point (``target_qm``) and whether the
        reference is captured (at ``captured_qm``): a capture farther than
        :data:`FAR_M` from the mark leaves step 1 unticked, marked."""
        if qm is not None:
            self.qm = np.asarray(qm, dtype=float)
        if target_qm is not None:
            self.target_qm = np.asarray(target_qm, dtype=float)
        if captured is not None:
            self.captured = bool(captured)
        if captured_qm is not None:
            self.captured_qm = np.asarray(captured_qm, dtype=float)
        self.distance_to_target = self._distance(self.qm)
        self.capture_offset = self._distance(self.captured_qm) if self.captured else None
        far = self.capture_offset is not None and self.capture_offset > FAR_M
        self.warned = {0} if far else set()
        if self.captured:
            self.done, self.step = ({1, 2} if far else {0, 1, 2}), (0 if far else 3)
        elif self.distance_to_target is not None and self.distance_to_target < NEAR_M:
            self.done, self.step = {0}, 1
        else:
            self.done, self.step = set(), 0
        self._changed()

    def _changed(self) -> None:
        self.update()

    def headline(self) -> tuple[str, str] | None:
        """``(text, colour)`` of the line over the picture (None: none)."""
        u = self.units
        if self.distance_to_target is not None and not self.captured:
            d = round(self.distance_to_target, 6)
            return (f"end effector \u2248 {u.text(d, 'm', '.4g')} from the mark (nominal model)",
                    INK)
        if self.captured and self.warned:
            return (f"\u26a0 reference captured {u.text(self.capture_offset, 'm', '.4g')} from "
                    "the mark", BAD)
        if self.captured:
            return "\u2713 reference captured", OK
        return None


class ArmPicture(ReferenceSteps, _Picture):
    """Side view of the serial arm; ``set_state`` with the readings."""

    def __init__(self, robot, nominal, parent=None, target_label: str = "base origin",
                 units=MM_DEG):
        _Picture.__init__(self, parent)
        self._init_steps(robot, nominal, target_label, units)

    def points(self, qm):
        """Joint points of the arm in its plane (m) and the rail position z (m)."""
        q = self.robot.chain.joints(np.atleast_2d(np.asarray(qm, dtype=float)), self.xi)[0]
        x0, y0, _ = self.robot.base_offset(self.xi)
        L2, L3, L4 = (self.xi[self.robot.index(n)] for n in ("L2", "L3", "L4"))
        pts = [(x0, y0)]
        a = math.pi / 2
        for length, dq in ((L2, q[1]), (L3, q[2]), (L4, q[3])):
            a += dq
            x, y = pts[-1]
            pts.append((x + length * math.cos(a), y + length * math.sin(a)))
        return pts, float(q[0])

    def paintEvent(self, _event) -> None:
        p = QPainter(self)
        p.setRenderHint(QPainter.RenderHint.Antialiasing)
        w, h = self.width(), self.height()
        p.fillRect(self.rect(), QColor("#fbfbfb"))
        text_h = 96
        view = QRectF(10, 8, w * 0.74 - 10, h - text_h - 16)
        rail = QRectF(w * 0.74 + 10, 8, w * 0.26 - 20, h - text_h - 16)
        reach = sum(self.xi[self.robot.index(n)] for n in ("L2", "L3", "L4"))
        x0, y0, _ = self.robot.base_offset(self.xi)
        lo = np.array([x0 - reach, min(0.0, y0 - reach * 0.6)])
        hi = np.array([x0 + reach, y0 + reach])
        s = min(view.width() / (hi[0] - lo[0]), view.height() / (hi[1] - lo[1]))

        def P(x, y):
            return QPointF(view.left() + (x - lo[0]) * s, view.bottom() - (y - lo[1]) * s)

        p.setPen(QPen(QColor("#999"), 1, Qt.PenStyle.DashLine))
        p.drawLine(P(lo[0], 0), P(hi[0], 0))
        p.setPen(QColor("#777"))
        p.drawText(P(lo[0], 0) + QPointF(4, 14), "floor (y = 0)")
        target = None
        if self.target_qm is not None:
            tpts, _ = self.points(self.target_qm)
            target = P(*tpts[-1])
            p.setPen(QPen(QColor(TARGET), 2))
            p.setBrush(Qt.BrushStyle.NoBrush)
            p.drawEllipse(target, 12, 12)
            p.drawLine(target + QPointF(-18, 0), target + QPointF(18, 0))
            p.drawLine(target + QPointF(0, -18), target + QPointF(0, 18))
        if self.qm is not None:
            pts, _ = self.points(self.qm)
            qp = [P(*pt) for pt in pts]
            p.setPen(QPen(QColor(INK), 3))
            p.drawLine(qp[0], P(pts[0][0], 0))
            p.setPen(QPen(QColor(ARM), 7, Qt.PenStyle.SolidLine, Qt.PenCapStyle.RoundCap))
            for a, b in itertools.pairwise(qp):
                p.drawLine(a, b)
            p.setPen(QPen(QColor(INK), 1.5))
            p.setBrush(QBrush(QColor("white")))
            for pt in qp[:-1]:
                p.drawEllipse(pt, 5, 5)
            p.setBrush(QBrush(QColor(INK)))
            p.drawEllipse(qp[-1], 5, 5)
            if target is not None:
                if self.captured or self.step == 1:
                    sensor = target + QPointF(70, 56)
                    p.setBrush(QBrush(QColor("#ddd")))
                    p.setPen(QPen(QColor(INK), 1))
                    p.drawRect(QRectF(sensor - QPointF(14, 10), sensor + QPointF(14, 10)))
                    p.drawText(sensor + QPointF(-26, 28), "draw-wire")
                    pen = QPen(QColor(CABLE), 2,
                               Qt.PenStyle.SolidLine if self.captured else Qt.PenStyle.DashLine)
                    p.setPen(pen)
                    p.drawLine(sensor, qp[-1])
                elif self.distance_to_target is not None:
                    p.setPen(QPen(QColor(TARGET), 1.5, Qt.PenStyle.DashLine))
                    p.drawLine(qp[-1], target)
            self._rail(p, rail)
            # labels last, on a light box, each away from the arm's last link
            away = qp[-1] - qp[-2]
            n = math.hypot(away.x(), away.y()) or 1.0
            ee_dir = QPointF(away.x() / n, away.y() / n)
            _label(p, qp[-1], "end effector", ee_dir, INK, view)
            if target is not None:
                d = target - qp[-1]
                dn = math.hypot(d.x(), d.y())
                t_dir = QPointF(d.x() / dn, d.y() / dn) if dn > 1 else QPointF(-ee_dir.x(),
                                                                             -ee_dir.y())
                _label(p, target, self.target_label, t_dir, TARGET, view, gap=22)
        elif target is not None:
            _label(p, target, self.target_label, QPointF(0.7, -0.7), TARGET, view, gap=22)
        head = self.headline()
        if head is not None:
            p.setPen(QColor(head[1]))
            p.drawText(QPointF(view.left(), view.top() + 14), head[0])
        self._steps(p, QRectF(10, h - text_h, w - 20, text_h))
        p.end()

    def _rail(self, p: QPainter, r: QRectF) -> None:
        lo, hi = self.robot.joint_limits[0]
        _, z = self.points(self.qm)
        p.setPen(QPen(QColor(INK), 1))
        p.drawText(QPointF(r.left(), r.top() + 14), "rail (seen from above)")
        x = r.left() + 30
        top, bottom = r.top() + 30, r.bottom() - 10
        p.setPen(QPen(QColor("#888"), 6))
        p.drawLine(QPointF(x, top), QPointF(x, bottom))

        def Y(zz):
            return bottom - (zz - lo) / (hi - lo) * (bottom - top)

        if self.target_qm is not None:
            _, zt = self.points(self.target_qm)
            p.setPen(QPen(QColor(TARGET), 2))
            p.drawLine(QPointF(x - 22, Y(zt)), QPointF(x + 22, Y(zt)))
        p.setPen(QPen(QColor(INK), 1))
        p.setBrush(QBrush(QColor(ARM)))
        p.drawRect(QRectF(x - 14, Y(z) - 8, 28, 16))
        p.drawText(QPointF(x + 20, Y(z) + 4), f"z {self.units.text(z, 'm', '.4g')}")


def _label(p: QPainter, anchor: QPointF, text: str, direction: QPointF, color: str,
           bounds: QRectF, gap: float = 12) -> None:
    """``text`` on a light box beside ``anchor``, ``gap`` pixels along ``direction``
    (a unit vector) and extending away from it, kept inside ``bounds``."""
    fm = p.fontMetrics()
    w, h = fm.horizontalAdvance(text) + 8, fm.height() + 2
    c = anchor + QPointF(direction.x() * (gap + w / 2), direction.y() * (gap + h / 2))
    box = QRectF(c.x() - w / 2, c.y() - h / 2, w, h)
    box.moveLeft(max(bounds.left(), min(box.left(), bounds.right() - w)))
    box.moveTop(max(bounds.top() + 18, min(box.top(), bounds.bottom() - h)))
    p.setPen(Qt.PenStyle.NoPen)
    p.setBrush(QBrush(QColor(255, 255, 255, 215)))
    p.drawRoundedRect(box, 3, 3)
    p.setPen(QColor(color))
    p.drawText(box, Qt.AlignmentFlag.AlignCenter, text)


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

    def paintEvent(self, _event) -> None:
        p = QPainter(self)
        p.setRenderHint(QPainter.RenderHint.Antialiasing)
        w, h = self.width(), self.height()
        p.fillRect(self.rect(), QColor("#fbfbfb"))
        text_h = 80
        left = QRectF(10, 10, w * 0.5 - 20, h - text_h - 20)
        c = left.center()
        pitch = self.pitch or 0.0
        p.save()
        p.translate(c)
        p.rotate(-math.degrees(pitch) * 5)          # exaggerated, as a hint
        p.setPen(QPen(QColor(INK), 1.5))
        p.setBrush(QBrush(QColor("#cfd8dc")))
        p.drawRect(QRectF(-left.width() * 0.4, 0, left.width() * 0.8, 14))
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
        p.drawText(QPointF(left.left(), left.top() + 14), "platform (side view, tilt \u00d75)")
        right = QRectF(w * 0.5 + 10, 10, w * 0.5 - 20, h - text_h - 20)
        rc = right.center()
        R = min(right.width(), right.height()) * 0.4
        p.setPen(QPen(QColor("#999"), 1))
        p.setBrush(Qt.BrushStyle.NoBrush)
        p.drawEllipse(rc, R, R)
        p.drawLine(rc - QPointF(R, 0), rc + QPointF(R, 0))
        p.drawLine(rc - QPointF(0, R), rc + QPointF(0, R))
        p.setPen(QPen(QColor(OK), 2))
        p.drawEllipse(rc, R / 2, R / 2)
        p.setPen(QColor(INK))
        p.drawText(QPointF(right.left(), right.top() + 14),
                   f"bubble level (green circle: \u00b1{math.degrees(MOUNT_TOLERANCE):.0f}\u00b0)")
        if self.roll is not None and self.pitch is not None:
            scale = (R / 2) / MOUNT_TOLERANCE
            off = QPointF(max(-R, min(R, self.roll * scale)), max(-R, min(R, -self.pitch * scale)))
            p.setBrush(QBrush(QColor(OK if self.level else BAD)))
            p.setPen(Qt.PenStyle.NoPen)
            p.drawEllipse(rc + off, 9, 9)
            p.setPen(QColor(OK if self.level else BAD))
            p.drawText(QPointF(right.left(), right.bottom()),
                       f"roll {math.degrees(self.roll):+.2f}\u00b0, pitch "
                       f"{math.degrees(self.pitch):+.2f}\u00b0 \u2014 "
                       + ("level: mounted flat" if self.level else "not level: check the mount"))
        self._steps(p, QRectF(10, h - text_h, w - 20, text_h))
        p.end()
