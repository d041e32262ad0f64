"""Pictures of what to do at the reference step, drawn with QPainter from the
live readings (no image files).

* :class:`ArmPicture` (serial arm): a side view of the arm in its vertical
  plane at the actuator values read now (nominal model), the point to bring
  the end effector to, the draw-wire cable (attached once captured), and the
  rail with the carriage; the steps, the current one in bold.
* :class:`station.gui.level_picture.LevelPicture` (wrist): the platform with the
  inclinometer on it and a bubble level of the roll and pitch read now against the
  mounting tolerance.
"""
from __future__ import annotations

import itertools
import math

import numpy as np
from PySide6.QtCore import QPointF, QRectF, Qt
from PySide6.QtGui import QBrush, QColor, QFont, QFontMetricsF, QPainter, QPen
from PySide6.QtWidgets import QSizePolicy, QWidget

from station.outputs.units import MM_DEG

INK, ARM, TARGET, CABLE, OK, BAD = ("#202124", "#3c6e9f", "#d35400", "#6a1b9a", "#1b7a2f",
                                     "#b3261e")
# the points on the tool (sm-markers): where the estimate puts them, and read now
MARKER_EST, MARKER_SEEN = "#e67e22", "#117a65"
NEAR_M = 0.01            # end effector this close to the target counts as there (m, nominal)
FAR_M = 0.05             # a reference captured farther from the mark is warned about (m)
MOUNT_TOLERANCE = math.radians(2.0)
RAIL_CAPTION = "rail\n(seen from above)"
READING_TEMPLATE = "roll +00.00\u00b0, pitch +00.00\u00b0 \u2014 not level: check the mount"
RAIL_X = 30              # the rail's line from its column's left edge (px)
RAIL_W = RAIL_X + 24     # the rail's column where its caption is above it (px)


WRAP = int(Qt.TextFlag.TextWordWrap)


def text_height(font: QFont, width: float, text: str, flags: int = 0) -> float:
    """The height of ``text`` word-wrapped at ``width`` pixels in ``font``."""
    if not text:
        return 0.0
    return QFontMetricsF(font).boundingRect(QRectF(0, 0, max(width, 1.0), 1e5),
                                            int(flags) | WRAP, text).height()


def draw_wrapped(p: QPainter, rect: QRectF, text: str, flags: int = 0) -> float:
    """``text`` word-wrapped in ``rect``'s width from its top (a word longer than the
    width is broken anywhere rather than cut); returns the height it took."""
    flags = int(flags) | WRAP
    probe = QRectF(rect.left(), rect.top(), max(rect.width(), 1.0), 1e5)
    br = p.boundingRect(probe, flags, text)
    if br.width() > probe.width() + 0.5:                 # a word wider than the rect
        flags = (flags & ~WRAP) | int(Qt.TextFlag.TextWrapAnywhere)
        br = p.boundingRect(probe, flags, text)
    p.drawText(QRectF(rect.left(), rect.top(), probe.width(), br.height() + 1), flags, text)
    return br.height()


class _Picture(QWidget):
    def __init__(self, parent=None):
        super().__init__(parent)
        self.setMinimumSize(380, 280)
        self.setSizePolicy(QSizePolicy.Policy.Expanding, QSizePolicy.Policy.Expanding)
        self.steps: list[str] = []
        self.step = 0                  # the current step (bold)
        self.done: set[int] = set()    # the steps ticked
        self.warned: set[int] = set()  # steps marked as not done as asked

    def _step_lines(self):
        """``(font, colour, text)`` of each step, the current one in bold."""
        for i, text in enumerate(self.steps):
            f = QFont(self.font())
            f.setBold(i == self.step)
            color = BAD if i in self.warned else "#777" if i in self.done else INK
            mark = "!" if i in self.warned else "\u2713" if i in self.done else f"{i + 1}."
            yield f, color, f"{mark} {text}"

    def _steps_height(self, width: float) -> float:
        """The height the steps take word-wrapped at ``width`` (0 without steps)."""
        return sum(text_height(f, width, text) + 4 for f, _, text in self._step_lines())

    def _steps(self, p: QPainter, rect: QRectF) -> None:
        y = rect.top()
        for f, color, text in self._step_lines():
            p.setFont(f)
            p.setPen(QColor(color))
            y += draw_wrapped(p, QRectF(rect.left(), y, rect.width(), 0), text) + 4
        p.setFont(self.font())


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

    def _z_text(self, z: float) -> str:
        return f"z {self.units.text(z, 'm', '.4g')}"

    def _rail_text(self) -> str:
        """The rail's caption and the carriage's position now."""
        if self.qm is None:
            return RAIL_CAPTION
        return f"{RAIL_CAPTION}\n{self._z_text(self.points(self.qm)[1])}"

    def _rail_text_width(self, fm: QFontMetricsF) -> float:
        """The widest line of :meth:`_rail_text` (``z`` with four digits and a sign
        at least, so the layout does not follow every reading)."""
        lines = RAIL_CAPTION.split("\n") + [self._z_text(-0.8888)]
        lines += self._rail_text().split("\n")
        return math.ceil(max(fm.horizontalAdvance(t) for t in lines)) + 4

    def paintEvent(self, _event) -> None:
        p = QPainter(self)
        p.setRenderHint(QPainter.RenderHint.Antialiasing)
        w, h = self.width(), self.height()
        p.fillRect(self.rect(), QColor("#fbfbfb"))
        fm = QFontMetricsF(self.font())
        # from the top: the headline; the view of the arm beside the rail, the rail's
        # caption over it; the steps. Every text is measured first: none is cut at the
        # picture's edge. The caption beside the view where the picture is wide, above
        # both where it is narrow (the view keeps its width, the arm its size).
        steps_h = self._steps_height(w - 20)
        bottom = h - (steps_h + 8 if steps_h else 0) - 6
        head = self.headline()
        top = 8.0
        if head is not None:
            p.setPen(QColor(head[1]))
            top += draw_wrapped(p, QRectF(10, top, w - 20, 0), head[0]) + 4
        text_w = min(self._rail_text_width(fm), w - 20)
        side = text_w <= w * 0.26
        rail_w = text_w if side else RAIL_W
        text_r = QRectF(w - 10 - text_w, top, text_w, 0)
        p.setPen(QPen(QColor(INK), 1))
        text_h = draw_wrapped(p, text_r, self._rail_text(),
                              int(Qt.AlignmentFlag.AlignLeft if side
                                  else Qt.AlignmentFlag.AlignRight))
        view_top = top if side else top + text_h + 6
        rail = QRectF(w - 10 - rail_w, top + text_h + 6, rail_w, bottom - top - text_h - 6)
        # the floor's caption below its line, inside the view
        view = QRectF(10, view_top, w - 30 - rail_w, bottom - view_top - fm.height() - 4)
        reach = sum(self.xi[self.robot.index(n)] for n in ("L2", "L3", "L4"))
        x0, y0, _ = self.robot.base_offset(self.xi)
        lo = np.array([x0 - reach, min(0.0, y0 - reach * 0.6)])
        hi = np.array([x0 + reach, y0 + reach])
        s = max(1e-9, min(view.width() / (hi[0] - lo[0]), view.height() / (hi[1] - lo[1])))

        def P(x, y):
            return QPointF(view.left() + (x - lo[0]) * s, view.bottom() - (y - lo[1]) * s)

        p.setPen(QPen(QColor("#999"), 1, Qt.PenStyle.DashLine))
        p.drawLine(P(lo[0], 0), P(hi[0], 0))
        p.setPen(QColor("#777"))
        floor = P(lo[0], 0) + QPointF(4, 2)
        p.drawText(floor + QPointF(0, fm.ascent()), "floor (y = 0)")
        taken = [QRectF(floor.x(), floor.y(), fm.horizontalAdvance("floor (y = 0)"),
                        fm.height())]
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
                    # the sensor below and right of the mark, it and its caption in the view
                    label_w = fm.horizontalAdvance("draw-wire") + 8
                    sensor = target + QPointF(70, 56)
                    sensor.setX(max(view.left() + label_w / 2,
                                    min(sensor.x(), view.right() - label_w / 2)))
                    sensor.setY(max(view.top() + 12,
                                    min(sensor.y(), view.bottom() - 14 - fm.height())))
                    p.setBrush(QBrush(QColor("#ddd")))
                    p.setPen(QPen(QColor(INK), 1))
                    p.drawRect(QRectF(sensor - QPointF(14, 10), sensor + QPointF(14, 10)))
                    caption = QRectF(sensor.x() - label_w / 2, sensor.y() + 12, label_w,
                                     fm.height() + 1)
                    p.drawText(caption, Qt.AlignmentFlag.AlignCenter, "draw-wire")
                    taken.append(caption)
                    pen = QPen(QColor(CABLE), 2,
                               Qt.PenStyle.SolidLine if self.captured else Qt.PenStyle.DashLine)
                    p.setPen(pen)
                    p.drawLine(sensor, qp[-1])
                elif self.distance_to_target is not None:
                    p.setPen(QPen(QColor(TARGET), 1.5, Qt.PenStyle.DashLine))
                    p.drawLine(qp[-1], target)
            self._rail(p, rail)
            # labels last, on a light box, each away from the arm's last link and from
            # the texts already drawn
            away = qp[-1] - qp[-2]
            n = math.hypot(away.x(), away.y()) or 1.0
            ee_dir = QPointF(away.x() / n, away.y() / n)
            taken.append(_label(p, qp[-1], "end effector", ee_dir, INK, view, avoid=taken))
            if target is not None:
                d = target - qp[-1]
                dn = math.hypot(d.x(), d.y())
                t_dir = QPointF(d.x() / dn, d.y() / dn) if dn > 1 else QPointF(-ee_dir.x(),
                                                                             -ee_dir.y())
                _label(p, target, self.target_label, t_dir, TARGET, view, gap=22, avoid=taken)
        elif target is not None:
            _label(p, target, self.target_label, QPointF(0.7, -0.7), TARGET, view, gap=22,
                   avoid=taken)
        self._steps(p, QRectF(10, h - steps_h - 6, w - 20, steps_h))
        p.end()

    def _rail(self, p: QPainter, r: QRectF) -> None:
        """The rail from above in ``r``: its limits, the reference's mark, the carriage."""
        lo, hi = self.robot.joint_limits[0]
        _, z = self.points(self.qm)
        x = r.left() + RAIL_X
        top, bottom = r.top() + 10, r.bottom() - 10
        p.setPen(QPen(QColor("#888"), 6))
        p.drawLine(QPointF(x, top), QPointF(x, bottom))

        def Y(zz):       # off the rail's ends (past a limit): drawn at the end
            return max(top, min(bottom, bottom - (zz - lo) / (hi - lo) * (bottom - top)))

        if self.target_qm is not None:
            _, zt = self.points(self.target_qm)
            p.setPen(QPen(QColor(TARGET), 2))
            p.drawLine(QPointF(x - 22, Y(zt)), QPointF(x + 22, Y(zt)))
        p.setPen(QPen(QColor(INK), 1))
        p.setBrush(QBrush(QColor(ARM)))
        p.drawRect(QRectF(x - 14, Y(z) - 8, 28, 16))


def _label(p: QPainter, anchor: QPointF, text: str, direction: QPointF, color: str,
           bounds: QRectF, gap: float = 12, avoid=()) -> QRectF:
    """``text`` on a light box beside ``anchor``, ``gap`` pixels along ``direction``
    (a unit vector) and extending away from it, kept inside ``bounds``; where that box
    would cover one of ``avoid`` (texts drawn already), the first of the other sides
    that does not. Returns the box."""
    fm = p.fontMetrics()
    w, h = fm.horizontalAdvance(text) + 8, fm.height() + 2

    def place(d: QPointF) -> QRectF:
        c = anchor + QPointF(d.x() * (gap + w / 2), d.y() * (gap + h / 2))
        box = QRectF(c.x() - w / 2, c.y() - h / 2, w, h)
        box.moveLeft(max(bounds.left(), min(box.left(), bounds.right() - w)))
        box.moveTop(max(bounds.top(), min(box.top(), bounds.bottom() - h)))
        return box

    sides = [direction, QPointF(-direction.x(), -direction.y()), QPointF(0, -1),
             QPointF(0, 1), QPointF(-1, 0), QPointF(1, 0)]
    box = next((b for b in map(place, sides) if not any(b.intersects(a) for a in avoid)),
               place(direction))
    p.setPen(Qt.PenStyle.NoPen)
    p.setBrush(QBrush(QColor(255, 255, 255, 215)))
    p.drawRoundedRect(box, 3, 3)
    p.setPen(QColor(color))
    p.drawText(box, Qt.AlignmentFlag.AlignCenter, text)
    return box
