"""Page 4, Execute: measure the planned poses with progress, the current pose
and live readings; pause, resume, abort; a device fault asks Retry / Skip /
Abort. Every recorded pose is in the trace at once (closing loses none). A URDF robot
measured by a motion capture (sm-markers): its markers live, in mm, a marker not seen
said so (no fault), and in the picture where the current estimate puts them."""
from __future__ import annotations

import time

from PySide6.QtCore import Qt
from PySide6.QtGui import QColor
from PySide6.QtWidgets import (QGroupBox, QHBoxLayout, QListWidget, QListWidgetItem,
                               QMessageBox, QProgressBar, QPushButton, QVBoxLayout)

from station.gui import fault_dialog
from station.gui.pages.base import Page, error_text
from station.gui.widgets import (BAD_COLOR, OK_COLOR, WARN_COLOR, ReadingsPanel,
                                 marker_channels, markers_text, note, target_coords)

#: the same fault this many times on one pose: Skip is suggested (the default button)
REPEATED_FAULT = 3

EVENT_COLOR = {"fault": BAD_COLOR, "abort": BAD_COLOR, "skip": WARN_COLOR, "retry": WARN_COLOR,
               "warning": WARN_COLOR, "remeasure": WARN_COLOR, "remeasure-failed": WARN_COLOR,
               "confirmed": BAD_COLOR}


class ExecutePage(Page):
    title = "Execute"
    subtitle = ("The robot drives to each planned pose, waits until it settles and records "
                "the readings; a reading the calibration would reject is measured again "
                "before the robot is released. Each pose is written to the trace at once: "
                "closing the window loses none, and opening the same session folder again "
                "resumes.")

    def __init__(self, controller, parent=None):
        super().__init__(controller, parent)
        self.progress = QProgressBar()
        self.progress.setFormat("%v of %m poses")
        self.layout_.addWidget(self.progress)
        self.current = note("")
        self.layout_.addWidget(self.current)
        buttons = QHBoxLayout()
        self.start_button = QPushButton("&Start measuring")
        self.pause_button = QPushButton("&Pause")
        self.resume_button = QPushButton("Res&ume")
        self.abort_button = QPushButton("&Abort")
        for b, slot in ((self.start_button, self.start), (self.pause_button, self.pause),
                        (self.resume_button, self.resume), (self.abort_button, self.abort)):
            b.setAutoDefault(False)
            b.clicked.connect(slot)
            buttons.addWidget(b)
        buttons.addStretch(1)
        self.layout_.addLayout(buttons)
        row = QHBoxLayout()
        box = QGroupBox("Readings (the last pose recorded, or live)")
        self.readings = ReadingsPanel()
        inner = QVBoxLayout(box)
        inner.addWidget(self.readings)
        inner.addStretch(1)
        row.addWidget(box, 1)
        self.picture_box = QGroupBox("The robot now (the model at the readings)")
        QVBoxLayout(self.picture_box)
        self.picture = None
        self._picture_for = None
        row.addWidget(self.picture_box, 2)
        box = QGroupBox("What happened")
        self.log = QListWidget()
        self.log.setMinimumHeight(220)
        self.log.setWordWrap(True)
        self.log.setHorizontalScrollBarPolicy(Qt.ScrollBarPolicy.ScrollBarAlwaysOff)
        QVBoxLayout(box).addWidget(self.log)
        row.addWidget(box, 2)
        self.layout_.addLayout(row, 1)
        self.status = note("")
        self.layout_.addWidget(self.status)
        self.running = False
        self.finished = False
        self.fault_box: QMessageBox | None = None
        self.faults_asked = 0
        self._faults_seen: dict[int, list[str]] = {}   # pose index -> the faults asked there
        self._restart = False      # Retry answered where the devices were lost
        controller.progressed.connect(self._progress)
        controller.eventLogged.connect(self._event)
        controller.stateChanged.connect(self._state)
        controller.valuesChanged.connect(self._values)
        controller.polled.connect(self._polled)
        controller.faults.asked.connect(self.ask_fault)
        controller.sessionChanged.connect(self._session_changed)

    def initialize_page(self) -> None:
        s = self.session
        if s is None:
            return
        self.readings.set_channels([f"qm{i + 1}" for i in range(s.robot.n_actuators)]
                                   + list(self._channels(s)))
        if self._picture_for != id(s):
            self._build_picture(s)
        if s.method == "sm-markers" and not self.running and not self.controller.jobs.busy:
            self.controller.run(lambda s: s.kind.estimate(), lambda _: self._estimated())
        if not self.running and s.plan_poses and not s.pending and s.rounds_complete:
            self.finished = True
        self._update_progress()
        self._buttons()

    def _build_picture(self, s) -> None:
        """The session's robot as the reference page draws it, following the readings
        (a robot file's arm in 3D, AGEBOT's arm from the side, the wrist's level)."""
        from station.gui.arm3d import ArmFigure
        from station.gui.level_picture import LevelPicture
        from station.gui.pictures import ArmPicture

        lay = self.picture_box.layout()
        if self.picture is not None:
            lay.removeWidget(self.picture)
            self.picture.deleteLater()
        units = self.controller.units
        if getattr(s, "method", None) == "sm-markers":     # the markers on the tool
            pic = ArmFigure(s.robot, s.nominal, units=units, labels=tuple(s.kind.labels))
        elif s.serial:
            pic = ArmFigure(s.robot, s.nominal, target_label="reference", units=units)
        elif s.robot.name == "agebot-sm":
            pic = ArmPicture(s.robot, s.nominal, target_label="reference", units=units)
        else:
            pic = LevelPicture()
        pic.steps = []                 # the reference's steps are done: the robot only
        if s.reference_qm is not None and hasattr(pic, "set_state"):
            pic.set_state(target_qm=s.reference_qm, captured=True, captured_qm=s.reference_qm)
        pic.setMinimumSize(300, 240)
        lay.addWidget(pic)
        pic.show()
        self.picture, self._picture_for = pic, id(s)

    def _show_robot(self, values: dict) -> None:
        from station.gui.arm3d import ArmFigure
        from station.gui.level_picture import LevelPicture

        pic, s = self.picture, self.session
        if pic is None or s is None:
            return
        if isinstance(pic, LevelPicture):
            if "roll" in values:
                pic.set_angles(values["roll"], values.get("pitch", 0.0))
            return
        if isinstance(pic, ArmFigure) and pic.labels:
            pic.set_markers(values)
        qm = [values.get(f"qm{i + 1}") for i in range(s.robot.n_actuators)]
        if None not in qm:
            pic.set_state(qm=qm)
            if isinstance(pic, ArmFigure) and "roll" in values:
                pic.set_tilt(values["roll"], values.get("pitch", 0.0))

    def _estimated(self) -> None:
        """The picture's markers where the session's current estimate puts them."""
        from station.gui.arm3d import show_estimate

        show_estimate(self.picture, self.session)

    @staticmethod
    def _channels(s):
        if getattr(s, "method", None) == "sm-markers":
            return marker_channels(len(s.kind.labels))
        if s.serial:
            return (("roll", "pitch") if "tilt" in s.info.channels else ()) + ("distance",)
        if s.robot.name == "agebot-sm":
            return ("tilt", "distance")
        return ("roll", "pitch", "yaw")

    def _session_changed(self) -> None:
        self._faults_seen, self._markers = {}, ""
        self.finished = False
        self.running = False
        self.log.clear()
        s = self.session
        for ev in (s.events if s is not None else ()):    # a resumed session's history
            self._event(ev, stamp=str(ev.get("t", ""))[11:19])
        # a resumed session measured whole: this step stays done
        self.finished = bool(s is not None and s.plan_poses and not s.pending
                             and s.rounds_complete)
        self.completeChanged.emit()

    def _update_progress(self) -> None:
        s = self.session
        if s is None:
            return
        done = len(s.measured) + len(s.skipped)
        self.progress.setMaximum(max(1, len(s.plan_poses)))
        self.progress.setValue(done)
        if not self.running:
            pending = len(s.pending)
            if pending:
                self.current.setText(f"{len(s.measured)} poses recorded, {len(s.skipped)} "
                                     f"skipped, {pending} to measure.")
            else:
                self.current.setText(f"All planned poses done: {len(s.measured)} recorded, "
                                     f"{len(s.skipped)} skipped.")

    def _buttons(self) -> None:
        s = self.session
        paused = bool(s is not None and s.paused)
        self.start_button.setEnabled(s is not None and not self.running and not self.finished)
        self.start_button.setText("&Continue measuring" if s is not None and s.measured
                                  and not self.running else "&Start measuring")
        self.pause_button.setEnabled(self.running and not paused)
        self.resume_button.setEnabled(self.running and paused)
        self.abort_button.setEnabled(self.running)
        self.completeChanged.emit()

    def is_complete(self) -> bool:
        return self.finished and not self.running

    # -- actions --------------------------------------------------------------------------------
    def start(self) -> None:
        if self.session is None or self.running:
            return
        self.running = True
        self.status.setStyleSheet("")
        self._buttons()
        if self.controller.devices_lost:      # e.g. the simulator's process ended
            self.status.setText("Connecting the devices again\u2026")
            self.controller.reopen(lambda _s: self._measure(), self._failed)
            return
        self._measure()

    def _measure(self) -> None:
        self.running = True
        self.status.setText("Measuring\u2026")
        self._buttons()
        self.controller.execute(self._done, self._failed)

    def pause(self) -> None:
        self.session.pause()
        self.status.setText("Paused after the current pose. Resume to go on.")
        self._buttons()

    def resume(self) -> None:
        self.session.resume()
        self.status.setText("Measuring\u2026")
        self._buttons()

    def abort(self) -> None:
        self.session.abort()
        self.status.setText("Aborting after the current pose\u2026")

    def _done(self, recorded: int) -> None:
        self.running = False
        self.finished = not self.session.pending
        self.status.setText(f"\u2713 Done: {recorded} poses recorded in this run. Press Next "
                            "to calibrate.")
        self.status.setStyleSheet(f"color: {OK_COLOR};")
        self._update_progress()
        self._buttons()

    def _failed(self, e) -> None:
        from station.session.execution import SessionAborted

        if self._restart:          # Retry after the devices were lost: connect, go on
            self._restart = False
            self.status.setText("Connecting the devices again\u2026")
            self.controller.reopen(lambda _s: self._measure(), self._failed)
            return
        self.running = False
        self._update_progress()
        self._buttons()
        if isinstance(e, SessionAborted):
            self.status.setText(f"Stopped: {error_text(e)}. Continue measuring picks up the "
                                "poses not yet measured.")
        else:
            self.status.setText(f"Measuring stopped: {error_text(e)}")
            self.show_error("Measuring stopped", e)
        self.status.setStyleSheet(f"color: {BAD_COLOR};")

    # -- a device fault: Retry / Skip / Abort ---------------------------------------------------
    def ask_fault(self, request) -> None:
        """The worker waits for the answer; the dialog is window-modal, not blocking."""
        self.faults_asked += 1
        pose = request.pose
        lost = self.controller.devices_lost
        gone = ""
        if self.controller.simulate:
            if lost:
                gone = ("The simulator's process has stopped: every simulated device is "
                        "gone, not only the one named below.\n\n")
                retry_text = ("Retry: start the simulator again, connect its devices, go "
                              "back to the reference and measure the pose again.")
            else:
                retry_text = "Retry: measure the pose again (the simulated device answers again)."
        elif lost:
            retry_text = ("Retry: connect the devices anew (check the named device's cable "
                          "and power first), go back to the reference and measure the pose "
                          "again.")
        else:
            retry_text = ("Retry: measure the pose again (a drive in FAULT is reset by the "
                          "station; check the named device's cable and power if it comes "
                          "back).")
        text = error_text(request.error)
        seen = self._faults_seen.setdefault(pose.index, [])
        # the same fault a third time on this pose: the pose, not the device, is at fault
        repeated = seen.count(text) >= REPEATED_FAULT - 1
        seen.append(text)
        hint = (f"\n\nThe same fault came back {seen.count(text)} times on this pose: "
                "the pose is likely out of this robot's reach (a limit switch, the floor, "
                "an obstacle) rather than a flaky device. Skip is suggested."
                if repeated else "")
        informative = (
            f"{gone}{text}\n\n{retry_text}\nSkip: leave this pose out and go "
            "on.\nAbort: stop here; the recorded poses stay in the trace and you can "
            f"continue later.{hint}")

        def answer(req, choice):
            if choice == "retry" and self.controller.devices_lost:
                # the session cannot reconnect to devices that are gone: it stops, the
                # devices are connected anew and measuring goes on from this pose
                self._restart, choice = True, "reconnect"
            self.controller.faults.answer(req, choice)

        fault_dialog.ask(self, request, answer, name="faultDialog",
                         text=f"Pose {pose.index} could not be measured "
                              f"(attempt {request.attempt + 1}).",
                         informative=informative, skip_label="S&kip pose",
                         suggested="skip" if repeated else "retry")

    # -- what the session reports ----------------------------------------------------------------
    def _progress(self, p) -> None:
        if p.stage:               # the wrist: counted per round (scout, then main)
            self.progress.setMaximum(max(1, p.stage_total))
            self.progress.setValue(p.stage_done)
            self.progress.setFormat(("scout round" if p.stage == "scout" else p.stage)
                                    + ": %v of %m poses")
        else:
            self.progress.setMaximum(max(1, p.total))
            self.progress.setValue(p.done)
            s = self.session
            rounds = getattr(s, "rounds", None) if s is not None else None
            if rounds is not None and not s.rounds_complete:   # the plan grows round by round
                total = rounds.fit_total() + rounds.totals()[1]
                self.progress.setFormat(f"%v of %m poses planned so far (the rounds plan "
                                        f"{total} in all)")
            else:
                self.progress.setFormat("%v of %m poses")
        if p.pose is not None:
            s = self.session
            names, sis = target_coords(s.robot) if s is not None else (("",) * 3, ("rad",) * 3)
            u = self.controller.units
            target = ", ".join(f"{k} {u.text(v, si, '.4g')}"
                               for k, v, si in zip(names, p.pose.target, sis))
            use = "held out" if p.pose.use == "validation" else "fit"
            text = f"Pose {p.pose.index} ({use}): {p.message}; target {target}"
            if s is not None and s.method == "sm-markers":     # kept while moving on
                seen = markers_text(p.readings or {}, tuple(s.kind.labels), u)
                self._markers = seen or getattr(self, "_markers", "")
                text += f"\nmarkers (the last pose recorded): {self._markers}" \
                    if self._markers else ""
                self._estimated()
            self.current.setText(text)

    def _event(self, ev: dict, stamp: str | None = None) -> None:
        if ev.get("kind") == "plan":
            text = ev.get("message", "")
        else:
            text = f"[{ev.get('kind')}] {ev.get('message', '')}"
        item = QListWidgetItem(f"{stamp or time.strftime('%H:%M:%S')}  {text}")
        color = EVENT_COLOR.get(ev.get("kind", ""))
        if color:
            item.setForeground(QColor(color))
        self.log.addItem(item)
        self.log.scrollToBottom()
        self._update_progress()

    def _state(self, state: str) -> None:
        self._buttons()

    def _values(self, values: dict) -> None:
        self.readings.set_values(values)
        self._show_robot(values)

    def _polled(self, readings) -> None:
        values = {}
        for r in readings:
            values.update(r.values)
        self.readings.set_values(values)
        self._show_robot(values)
