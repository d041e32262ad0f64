"""Page 2, Reference: jog the actuators (step or continuous, under a speed
limit), watch distance and tilt live, see what to do, capture the reference;
for the wrist, the inclinometer mounting check; for a URDF robot measured by a motion
capture (sm-markers: no reference), the markers on the tool seen live."""
from __future__ import annotations

import numpy as np
from PySide6.QtCore import Qt
from PySide6.QtWidgets import (QButtonGroup, QCheckBox, QDoubleSpinBox, QFormLayout,
                               QGridLayout, QGroupBox, QHBoxLayout, QLabel, QPushButton,
                               QRadioButton, QVBoxLayout, QWidget)

from station.gui.pages.base import Page
from station.gui.arm3d import ArmFigure, marker_steps, show_estimate
from station.gui.level_picture import LevelPicture
from station.gui.pictures import FAR_M, ArmPicture, ReferenceSteps
from station.gui.widgets import (OK_COLOR, WARN_COLOR, ReadingsPanel, channel_text,
                                 marker_channels, note)


class JogPanel(QGroupBox):
    """Per actuator: its value now and - / + buttons; step or continuous (hold)."""

    def __init__(self, page: ReferencePage, n: int, velocities, step: float):
        super().__init__("Jog the actuators")
        self.page, self.velocities = page, list(velocities) or [1.0] * n
        lay = QVBoxLayout(self)
        modes = QHBoxLayout()
        self.step_mode = QRadioButton("S&tep")
        self.continuous_mode = QRadioButton("Contin&uous (hold the button)")
        self.step_mode.setChecked(True)
        group = QButtonGroup(self)
        group.addButton(self.step_mode)
        group.addButton(self.continuous_mode)
        modes.addWidget(self.step_mode)
        modes.addWidget(self.continuous_mode)
        lay.addLayout(modes)
        form = QFormLayout()
        self.step = QDoubleSpinBox()
        self.step.setRange(0.001, 1000.0)
        self.step.setDecimals(3)
        self.step.setValue(step)
        self.step.setSuffix(" u")
        self.step.setToolTip("u: the actuator unit of qm, the drives' position unit (the "
                             "station config's [canopen] increments_per_unit counts per u)")
        form.addRow("Step si&ze:", self.step)
        self.speed = QDoubleSpinBox()
        self.speed.setRange(1, 100)
        self.speed.setValue(25)
        self.speed.setSuffix(" % of the drive's profile velocity")
        form.addRow("Speed &limit:", self.speed)
        lay.addLayout(form)
        grid = QGridLayout()
        self.values: list[QLabel] = []
        self.buttons: list[tuple[QPushButton, QPushButton]] = []
        for i in range(n):
            grid.addWidget(QLabel(f"qm{i + 1}"), i, 0)
            val = QLabel("\u2013")
            val.setMinimumWidth(110)
            val.setAlignment(Qt.AlignmentFlag.AlignRight | Qt.AlignmentFlag.AlignVCenter)
            grid.addWidget(val, i, 1)
            self.values.append(val)
            pair = []
            for c, sign in ((2, -1), (3, +1)):
                b = QPushButton("\u2212" if sign < 0 else "+")
                b.setAutoDefault(False)
                b.setMinimumWidth(48)
                b.setToolTip(f"move qm{i + 1} {'down' if sign < 0 else 'up'}")
                b.setAccessibleName(f"jog qm{i + 1} {'minus' if sign < 0 else 'plus'}")
                b.clicked.connect(lambda _=False, a=i, s=sign: self._clicked(a, s))
                b.pressed.connect(lambda a=i, s=sign: self._pressed(a, s))
                b.released.connect(self._released)
                grid.addWidget(b, i, c)
                pair.append(b)
            self.buttons.append(tuple(pair))
        lay.addLayout(grid)
        self.stop = QPushButton("&Stop")
        self.stop.setAutoDefault(False)
        self.stop.clicked.connect(page.controller.stop_jog)
        lay.addWidget(self.stop)

    def speed_of(self, axis: int) -> float:
        return self.velocities[axis] * self.speed.value() / 100.0

    def _clicked(self, axis: int, sign: int) -> None:
        if self.step_mode.isChecked() and not self.page.controller.jobs.busy:
            self.page.controller.jog(axis, sign * self.step.value(), self.speed_of(axis),
                                     on_error=self.page.jog_failed)

    def _pressed(self, axis: int, sign: int) -> None:
        if self.continuous_mode.isChecked() and not self.page.controller.jobs.busy:
            self.page.controller.jog_continuous(axis, sign, self.speed_of(axis),
                                                on_error=self.page.jog_failed)

    def _released(self) -> None:
        if self.continuous_mode.isChecked():
            self.page.controller.stop_jog()

    def set_values(self, values: dict) -> None:
        for i, lab in enumerate(self.values):
            v = values.get(f"qm{i + 1}")
            if v is not None:
                lab.setText(" ".join(channel_text("qm", v)))


class ReferencePage(Page):
    title = "Reference"
    subtitle = ("Bring the robot to the reference and capture it. The picture shows what to do "
                "and follows the robot as you jog.")

    def __init__(self, controller, parent=None):
        super().__init__(controller, parent)
        self.container = QWidget()
        self.layout_.addWidget(self.container, 1)
        self._built_for = None
        self.jog = self.picture = self.readings = None
        self.capture_button = self.goto_button = self.rezero_button = self.confirm = None
        self.recapture_button = None
        self.status = note("")
        self.layout_.addWidget(self.status)
        controller.valuesChanged.connect(self._values)
        controller.polled.connect(self._polled)
        controller.busyChanged.connect(self._busy)

    # -- building for the session's robot -------------------------------------------------
    def _build(self, session) -> None:
        old = self.container
        self.container = QWidget()
        self.layout_.replaceWidget(old, self.container)
        old.deleteLater()
        lay = QHBoxLayout(self.container)
        lay.setContentsMargins(0, 0, 0, 0)
        left = QVBoxLayout()
        cfg = self.controller.config
        vel = list(cfg.canopen.profile_velocity) if cfg is not None else []
        n = session.robot.n_actuators
        if len(vel) == 1:
            vel = vel * n
        sm = session.robot.name == "agebot-sm"
        serial = session.serial                 # a robot file's arm
        labels = tuple(session.kind.labels) if session.method == "sm-markers" else ()
        self.jog = JogPanel(self, n, vel, 0.05 if serial else 1.0 if sm else 10.0)
        left.addWidget(self.jog)
        box = QGroupBox("Live readings")
        channels = (marker_channels(len(labels)) if labels else
                    ("distance", "roll", "pitch") if serial else ("distance", "tilt") if sm
                    else ("roll", "pitch", "yaw"))
        QVBoxLayout(box).addWidget(ReadingsPanel(channels, large=not labels,
                                                 marker_grid=bool(labels)))
        self.readings = box.findChild(ReadingsPanel)
        left.addWidget(box)
        left.addStretch(1)
        lay.addLayout(left, 0)
        right = QVBoxLayout()
        _, _, text = session.reference_target()
        self.subtitle_label.setText(
            "No reference to capture for sm-markers: check that the motion capture sees the "
            "markers on the tool (jog the robot if needed), then press Next." if labels
            else self.subtitle)
        if labels:              # the markers on the tool, no reference
            self.picture = ArmFigure(session.robot, session.nominal, units=self.controller.units,
                                     labels=labels)
            self.picture.steps = marker_steps(labels)
            text = ("The motion capture measures the markers in its own frame; the robot's "
                    "base is placed in that frame from the scout round's poses, so the picture "
                    "shows the markers from then on.")
        elif serial:
            _, role, _ = session.reference_target()
            self.picture = ArmFigure(session.robot, session.nominal,
                                     target_label=(role or "reference").replace("-", " "),
                                     units=self.controller.units)
        elif sm:
            _, role, _ = session.reference_target()
            self.picture = ArmPicture(session.robot, session.nominal,
                                      target_label=(role or "reference").replace("-", " "),
                                      units=self.controller.units)
        else:
            self.picture = LevelPicture()
        right.addWidget(self.picture, 1)
        right.addWidget(note(text))
        buttons = QHBoxLayout()
        if session.needs_reference:
            self.goto_button = QPushButton("&Go to the suggested point")
            self.goto_button.clicked.connect(self.go_to_target)
            self.capture_button = QPushButton("C&apture reference")
            self.capture_button.clicked.connect(self.capture)
            self.recapture_button = QPushButton("Capture a&gain here")
            self.recapture_button.setToolTip("zero the draw-wire here and record this pose as "
                                             "the reference instead (before any pose only)")
            self.recapture_button.clicked.connect(self.capture)
            self.rezero_button = QPushButton("Return to the reference and &re-zero")
            self.rezero_button.clicked.connect(self.rezero)
            for b in (self.goto_button, self.capture_button, self.recapture_button,
                      self.rezero_button):
                b.setAutoDefault(False)
                buttons.addWidget(b)
        elif not labels:
            self.confirm = QCheckBox("I &checked: mounted flat, x axis along the platform's x axis")
            self.confirm.toggled.connect(lambda _: self._refresh())
            buttons.addWidget(self.confirm)
        buttons.addStretch(1)
        right.addLayout(buttons)
        lay.addLayout(right, 1)
        self._built_for = id(session)

    def initialize_page(self) -> None:
        s = self.session
        if s is None:
            return
        if self._built_for != id(s):
            self._build(s)
        if isinstance(self.picture, ReferenceSteps):
            qm, _, _ = s.reference_target()
            self.picture.set_state(target_qm=qm, captured=s.reference_qm is not None,
                                   captured_qm=s.reference_qm)
        if s.method == "sm-markers" and not self.controller.jobs.busy:   # a resumed session's
            self.controller.run(lambda s: s.kind.estimate(), lambda _: self._estimated())
        self._values(self.controller.last_readings)
        self._refresh()

    def _refresh(self) -> None:
        s, c = self.session, self.controller
        if s is None or self.jog is None:
            return
        busy = c.jobs.busy
        if s.needs_reference:
            captured = s.reference_qm is not None
            again = captured and not s.measured          # no pose depends on it yet
            self.capture_button.setVisible(not captured)
            self.capture_button.setEnabled(not captured and not busy)
            self.recapture_button.setVisible(captured)
            self.recapture_button.setEnabled(again and not busy)
            self.goto_button.setEnabled((not captured or again) and not busy)
            self.rezero_button.setVisible(c.needs_rezero or (s.resumed and c.rezeroed))
            self.rezero_button.setEnabled(c.needs_rezero and not busy)
            if captured:
                units = c.units
                qm = units.vector(s.reference_qm, "u", ".6g")
                off = s.reference_offset()
                far = off is not None and off > FAR_M
                if far:
                    text = (f"\u26a0 Reference captured at qm {qm}, {units.text(off, 'm', '.4g')} "
                            f"from the suggested mark (nominal model). {self.role_note} If that "
                            "was not meant, jog to the mark (or \u2018Go to the suggested "
                            "point\u2019) and press \u2018Capture again here\u2019.")
                else:
                    text = f"\u2713 Reference captured at qm {qm}."
                    if again:
                        text += " Jog and \u2018Capture again here\u2019 to replace it."
                if c.needs_rezero:
                    text += (" The session was resumed: the draw-wire may have lost its zero. "
                             "Leave the cable attached and press \u2018Return to the reference "
                             "and re-zero\u2019 (Execute also does it before the first pose).")
                self._say(text, WARN_COLOR if far else OK_COLOR)
            else:
                self._say("Reference not captured yet.", None)
        elif s.method == "sm-markers":
            readings = self.picture.readings
            seen = 0 if readings is None else int(np.all(np.isfinite(readings), axis=1).sum())
            total = len(self.picture.labels)
            if readings is None:
                self._say("Waiting for the motion capture's first reading.", None)
            elif seen == total:
                self._say(f"\u2713 The motion capture sees the {total} markers. No reference "
                          "to capture: press Next.", OK_COLOR)
            else:
                self._say(f"The motion capture sees {seen} of the {total} markers now: a "
                          "marker not seen at a pose leaves it with fewer points (no fault). "
                          "Press Next when ready.", WARN_COLOR)
        else:
            level = self.picture.level
            if self.confirm.isChecked():
                self._say("\u2713 Mounting checked.", OK_COLOR)
            elif level is False:
                self._say("Roll or pitch is not near 0 at the home pose: check the mount, "
                          "then confirm.", None)
            else:
                self._say("Check the mounting, then confirm.", None)
        self.completeChanged.emit()

    def _say(self, text: str, color) -> None:
        self.status.setText(text)
        self.status.setStyleSheet(f"color: {color};" if color else "")

    def is_complete(self) -> bool:
        s = self.session
        if s is None:
            return False
        if s.needs_reference:
            return s.reference_qm is not None
        if s.method == "sm-markers":        # no reference: the markers seen here, by eye
            return self._built_for == id(s)
        return bool(self.confirm is not None and self.confirm.isChecked())

    def leave_page(self) -> None:
        self.controller.stop_jog()

    # -- actions -----------------------------------------------------------------------------
    def go_to_target(self) -> None:
        qm, _, _ = self.session.reference_target()
        if qm is not None:
            self.controller.move_to(qm, on_error=self.jog_failed)

    def capture(self) -> None:
        self.controller.run(lambda s: s.capture_reference(), self._captured,
                            lambda e: self.show_error("The reference was not captured", e))

    def _captured(self, qm) -> None:
        if isinstance(self.picture, ReferenceSteps):
            self.picture.set_state(captured=True, captured_qm=qm)
        self._refresh()

    @property
    def role_note(self) -> str:
        s = self.session
        if s is not None and s.method == "sm-distance-tilt" and s.serial:
            return "The calibrated base frame's origin will be this point."
        if s is not None and s.method == "sm-distance-tilt":
            return "theta0, a0 and q1_off will refer to this point."
        return "Distances will be measured from this point."

    def rezero(self) -> None:
        self.controller.rezero(lambda _: self._refresh(),
                               lambda e: self.show_error("Re-zeroing failed", e))

    def jog_failed(self, e) -> None:
        self.show_error("The move failed", e)

    # -- live values --------------------------------------------------------------------------
    def _polled(self, readings) -> None:
        values = {}
        for r in readings:
            values.update(r.values)
        self._values(values)

    def _values(self, values: dict) -> None:
        if self.jog is None or not values:
            return
        self.jog.set_values(values)
        self.readings.set_values(values)
        n = len(self.jog.values)
        qm = [values.get(f"qm{i + 1}") for i in range(n)]
        if isinstance(self.picture, ArmFigure) and self.picture.labels and "m1_x" in values:
            was = self.picture.readings
            self.picture.set_markers(values)
            if was is None or (np.isfinite(was) != np.isfinite(self.picture.readings)).any():
                self._refresh()          # a marker seen or lost
        if isinstance(self.picture, ReferenceSteps) and None not in qm:
            self.picture.set_state(qm=qm)
            if isinstance(self.picture, ArmFigure) and "roll" in values:
                self.picture.set_tilt(values["roll"], values.get("pitch", 0.0))
        elif isinstance(self.picture, LevelPicture) and "roll" in values:
            was = self.picture.level
            self.picture.set_angles(values["roll"], values.get("pitch", 0.0))
            if was != self.picture.level:
                self._refresh()

    def _estimated(self) -> None:
        show_estimate(self.picture, self.session)

    def _busy(self, _busy: bool) -> None:
        if self.isVisible():
            self._refresh()
