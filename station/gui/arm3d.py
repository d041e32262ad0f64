"""The arm of a robot file in 3D on the Qt canvas: :class:`ArmFigure` is the reference
page's live picture for a robot file: the arm at the encoders read now
(:mod:`station.gui.arm_drawing` draws it), the reference mark, the draw-wire's anchor and
its wire to the tool, the tool's inclinometer (its axes and the roll and pitch read now)
and the steps (:class:`station.gui.pictures.ReferenceSteps`).

A URDF robot measured by a motion capture (sm-markers, ``labels`` given) is drawn in its
base link's frame with the points on its tool: where the session's current estimate puts
them (:meth:`ArmFigure.set_estimate`) and where the motion capture sees them now
(:meth:`ArmFigure.set_markers`, brought into the base link's frame by the estimated
instrument frame); a point not seen is said so, over the picture.

Lengths are drawn in the display units (:func:`station.gui.widgets.display_units`).
"""
from __future__ import annotations

import math

import numpy as np
from PySide6.QtCore import QTimer
from PySide6.QtWidgets import QLabel, QVBoxLayout, QWidget

from station.gui.arm_drawing import (base_frame, draw_arm, draw_floor, draw_points, setup_axes,
                                     stick, to_base, tool_points, view_box)
from station.gui.pictures import BAD, CABLE, INK, MARKER_SEEN, TARGET, ReferenceSteps
from station.gui.plots import Canvas
from station.outputs.units import MM_DEG

INCL_AXIS = 0.12          # m: length of the inclinometer's drawn axes
MIN_WIDTH, MIN_HEIGHT = 380, 300     # px: the 3D view (and its size hint)
REDRAW_MS = 120           # coalesced redraws (the polling delivers readings every 0.4 s)


class ArmFigure(ReferenceSteps, QWidget):
    """The reference page's live 3D picture of a robot file's arm (module docstring):
    ``set_state`` with the actuators read, :meth:`set_tilt` with the inclinometer's;
    with ``labels`` (the points on the tool, sm-markers) :meth:`set_estimate` and
    :meth:`set_markers`."""

    def __init__(self, robot, nominal, parent=None, target_label: str = "reference point",
                 units=MM_DEG, home_qm=None, labels=()):
        QWidget.__init__(self, parent)
        self.labels = tuple(labels)
        # a URDF robot with points: drawn in its base link's frame (the instrument's frame
        # is what the session estimates)
        self._init_steps(robot, base_frame(robot, nominal) if self.labels else nominal,
                         target_label, units)
        self.roll = self.pitch = None
        self.frame = None           # the base link in the instrument's frame (estimated)
        self.points = None          # (M, 3) the points on the tool (estimated, tip link frame)
        self.readings = None        # (M, 3) the points read now (instrument frame; NaN: not seen)
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

    def set_estimate(self, xi, points) -> None:
        """The session's current estimate: ``xi`` (the robot with the instrument's frame)
        and ``points`` ``(M, 3)`` on the tool (m, tip link frame); None: not made yet."""
        if xi is None:
            self.frame = self.points = None
        else:
            self.frame = self.robot.frame_matrix(np.asarray(xi, dtype=float))
            self.xi = base_frame(self.robot, xi)
            self.points = np.asarray(points, dtype=float).reshape(-1, 3)
        self._changed()

    def set_markers(self, values: dict) -> None:
        """The motion capture's reading ``m1_x .. mM_z`` (m, its frame; NaN: not seen)."""
        if not self.labels or "m1_x" not in values:
            return
        self.readings = np.array([[values.get(f"m{k}_{a}", math.nan) for a in "xyz"]
                                  for k in range(1, len(self.labels) + 1)], dtype=float)
        self._changed()

    def marker_lines(self) -> list[tuple[str, str]]:
        """What the picture says of the points on the tool: seen, not seen, placed."""
        if not self.labels:
            return []
        if self.readings is None:
            lines = [("motion capture: no reading yet", "#555")]
        else:
            seen = np.all(np.isfinite(self.readings), axis=1)
            missing = [lab for lab, ok in zip(self.labels, seen) if not ok]
            text = f"motion capture: {int(seen.sum())} of {len(self.labels)} points seen"
            lines = [(text, MARKER_SEEN if not missing else BAD)]
            if missing:
                lines.append((f"not seen: {', '.join(missing)}", BAD))
        if self.frame is None:
            lines.append(("points drawn once the scout round placed the instrument", "#555"))
        else:
            lines.append(("\u25cb points as estimated, \u25cf as measured now", "#555"))
        return lines

    def _changed(self) -> None:
        if self.labels:          # no reference: the first step done once every marker is seen
            seen = self.readings is not None and bool(np.all(np.isfinite(self.readings)))
            self.done, self.step, self.warned = ({0}, 1, set()) if seen else (set(), 0, set())
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
        def r(v):       # NaN (a marker not seen) as None: equal to itself
            return None if v is None else tuple(
                round(float(x), 5) if math.isfinite(x) else None
                for x in np.asarray(v, dtype=float).ravel())
        return (r(self.qm), r(self.target_qm), r(self.captured_qm), self.captured, self.step,
                None if self.roll is None else round(self.roll, 4),
                None if self.pitch is None else round(self.pitch, 4),
                r(self.frame), r(self.points), r(self.readings), r(self.xi))

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
            if self.labels:
                self._points(ax, s.tool, scale)
            else:
                self._inclinometer(ax, s.tool, scale)
        setup_axes(ax, lo, hi, scale, unit)
        head = self.headline()
        lines = ([head] if head else []) + self.marker_lines()
        if self.roll is not None and self.pitch is not None and not self.labels:
            lines.append((f"inclinometer on the tool: roll {math.degrees(self.roll):+.2f}\u00b0, "
                          f"pitch {math.degrees(self.pitch):+.2f}\u00b0", "#555"))
        for k, (text, color) in enumerate(lines):
            # out of the constrained layout: a line wider than the figure (the Execute
            # page's third of the row) collapsed the axes to nothing
            ax.text2D(0.0, 1.0 - 0.06 * k, text, transform=ax.transAxes, fontsize=8,
                      color=color, va="top", in_layout=False)
        self.canvas.draw_idle()

    def _points(self, ax, T, scale: float) -> None:
        """The points on the tool: estimated (on the tool at ``T``) and read now (in the
        base link's frame by the estimated instrument frame); none before the estimate."""
        if self.frame is None or self.points is None:
            return
        measured = None if self.readings is None else to_base(self.frame, self.readings)
        draw_points(ax, tool_points(T, self.points), measured, scale)

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


def marker_estimate(session):
    """``(xi, points)`` of a sm-markers ``session``'s current estimate of the robot with
    the instrument's frame and of the points on the tool, as the session last made it
    (:meth:`station.session.marker_kind.MarkersKind.estimate` keeps it); None before the
    estimate placed the frame (fewer than 3 fit poses), or for another session. Read,
    not computed: safe while the session's worker measures."""
    if session is None or session.method != "sm-markers":
        return None
    return session.kind.last_estimate


def show_estimate(pic, session) -> None:
    """``pic`` (an :class:`ArmFigure` with markers; else nothing) with ``session``'s
    current estimate (:func:`marker_estimate`), drawn again only where it changed."""
    if not isinstance(pic, ArmFigure) or not pic.labels:
        return
    est = marker_estimate(session)
    if est is None:
        if pic.frame is not None:
            pic.set_estimate(None, None)
    elif pic.frame is None or not np.array_equal(pic.points, est[1]):
        pic.set_estimate(*est)


def marker_steps(labels) -> list[str]:
    """The Reference page's steps of a sm-markers session (no reference to capture)."""
    return [f"Check that the motion capture sees the {len(labels)} markers on the tool "
            f"({', '.join(labels)}): the live readings say \u2018not seen\u2019 for one it "
            "does not see (it may be turned away; the planner keeps them in sight).",
            "No reference to capture: press Next. The instrument's frame and where the "
            "markers sit on the tool are estimated from the scout round and calibrated with "
            "the robot."]
