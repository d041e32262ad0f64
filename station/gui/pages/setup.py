"""Page 1, Setup: robot and method, station config, session folder, device
connection with live status; what is missing is said in words with the fix."""
from __future__ import annotations

from pathlib import Path

from PySide6.QtWidgets import (QCheckBox, QComboBox, QFileDialog, QFormLayout, QGroupBox,
                               QHBoxLayout, QLineEdit, QMessageBox, QPushButton, QSpinBox,
                               QWidget)

from drivers.sim.serial_robot import is_robot_file
from station.gui.controller import ROBOTS, summarize_folder
from station.gui.pages.base import Page, error_text
from station.gui.pages.setup_choices import (DEFAULT_METHOD, METHOD_TEXT,  # noqa: F401
                                             ROBOT_FILES, ROUNDS_TEXT, RobotMethodChoice,
                                             default_folder, draw_truth_file, robot_model,
                                             sessions_root)
from station.gui.pages.setup_urdf import URDF_FILTER
from station.gui.widgets import BAD_COLOR, OK_COLOR, DeviceTable, note
from station.planning.request import PlanRequest


def _row(*widgets) -> QWidget:
    w = QWidget()
    lay = QHBoxLayout(w)
    lay.setContentsMargins(0, 0, 0, 0)
    for x in widgets:
        lay.addWidget(x, 1 if isinstance(x, QLineEdit) else 0)
    return w


class SetupPage(RobotMethodChoice, Page):
    title = "Setup"
    subtitle = ("Choose the robot and the calibration method, the station and a folder for "
                "this session, then connect the devices. The list above the Connect button says "
                "what is still missing and how to fix it.")

    def __init__(self, controller, parent=None):
        super().__init__(controller, parent)
        c = controller
        box = QGroupBox("Robot and method")
        form = QFormLayout(box)
        self.robot = QComboBox()
        for key, text in ROBOTS.items():
            self.robot.addItem(text, key)
        for path in sorted(ROBOT_FILES.glob("*.toml")) + sorted(ROBOT_FILES.glob("*.urdf")):
            self.add_robot_file(str(path))
        browse_robot = self.robot_file_button = QPushButton("Robot fi&le\u2026")
        browse_robot.setProperty("tip", "any serial arm described by a robot file "
                                        "(docs/robot-files.md) or a URDF "
                                        "(docs/urdf-robots.md)")
        browse_robot.setToolTip(browse_robot.property("tip"))
        browse_robot.clicked.connect(self.browse_robot_file)
        self.method = QComboBox()
        self.method_text = note("")
        # wide enough that its wrapped height is computed at about the width it gets
        # (a narrow guess leaves the box a third empty)
        self.method_text.setMinimumWidth(600)
        form.addRow("&Robot:", _row(self.robot, browse_robot))
        form.addRow("&Method:", self.method)
        form.addRow("", self.method_text)
        self._build_urdf_rows(form)          # a URDF robot's chain and instrument
        self.layout_.addWidget(box)

        box = QGroupBox("Station")
        form = QFormLayout(box)
        self.config = QLineEdit(c.config_path or "")
        self.config.setPlaceholderText("the station's config file (TOML)")
        browse = QPushButton("Bro&wse\u2026")
        browse.clicked.connect(self.browse_config)
        self.endpoints = QLineEdit(c.endpoints_path or "")
        self.endpoints.setPlaceholderText("optional: a running simulator's endpoints file")
        browse_ep = QPushButton("Browse\u2026")
        browse_ep.clicked.connect(self.browse_endpoints)
        self.truth = QLineEdit(c.truth_path or "")
        self.truth.setPlaceholderText("what the simulated arm really is (a truth file of "
                                      "the robot file)")
        browse_truth = QPushButton("Browse\u2026")
        browse_truth.clicked.connect(self.browse_truth)
        self.draw_truth_button = QPushButton("Dra&w one")
        self.draw_truth_button.setToolTip("a simulated arm drawn around the robot file's "
                                          "(or URDF's) nominal, saved in the session folder")
        self.draw_truth_button.clicked.connect(self.draw_truth)
        self.truth_row = _row(self.truth, browse_truth, self.draw_truth_button)
        if c.simulate:
            form.addRow("Devices:", note("simulated: the simulator starts in its own process "
                                         "when you connect (app.py simulate)"))
            form.addRow("Simulated tr&uth:", self.truth_row)
            if c.config_path:
                form.addRow("Station conf&ig:", self.config)
            self.config.setReadOnly(True)
        else:
            form.addRow("Station conf&ig:", _row(self.config, browse))
            form.addRow("&Endpoints:", _row(self.endpoints, browse_ep))
        self.layout_.addWidget(box)

        box = QGroupBox("Session")
        form = QFormLayout(box)
        self.folder = QLineEdit(default_folder())
        browse_f = QPushButton("Br&owse\u2026")
        browse_f.clicked.connect(self.browse_folder)
        self.folder_row = _row(self.folder, browse_f)
        form.addRow("Session fol&der:", self.folder_row)
        self.count = QSpinBox()
        self.count.setRange(0, 500)
        self.count.setSpecialValueText("automatic (twice the minimum of eq. 60)")
        self.count.setMinimumWidth(280)
        form.addRow("&Poses to fit:", self.count)
        # the arm's distance methods: rounds inside the live-watched envelope
        # (station/planning/arm_rounds.py), as app.py run does; unticked is its --one-shot
        self.rounds = QCheckBox(ROUNDS_TEXT)
        self.rounds.setChecked(True)
        self._rounds_wanted = True
        self.rounds.toggled.connect(self._rounds_toggled)
        self.rounds.setProperty("tip", "Unticked: every pose planned at once from the start "
                                "values, moves not watched (app.py run --one-shot); safe only "
                                "where the start values are close to the robot")
        self.rounds.setToolTip(self.rounds.property("tip"))
        # where the choice does not apply: how the poses are planned, said, not a box
        self.rounds_note = note("")
        form.addRow("", _row(self.rounds, self.rounds_note))
        self.layout_.addWidget(box)

        self.connect_button = QPushButton("&Connect")
        self.connect_button.setDefault(True)
        self.connect_button.clicked.connect(self.connect_session)
        self.disconnect_button = QPushButton("Disconnec&t")
        self.disconnect_button.clicked.connect(self.disconnect_session)
        # what is missing next to the Connect button: in sight without scrolling
        self.missing = note("")
        self.missing.setObjectName("missing")
        self.layout_.addWidget(self.missing)
        self.layout_.addWidget(_row(self.connect_button, self.disconnect_button))

        box = QGroupBox("Devices (live)")
        lay = QHBoxLayout(box)
        self.devices = DeviceTable()
        lay.addWidget(self.devices)
        self.layout_.addWidget(box)
        self.layout_.addStretch(1)

        self.robot.currentIndexChanged.connect(self._robot_changed)
        self.method.currentIndexChanged.connect(self._method_changed)
        self.folder.textChanged.connect(self.update_missing)
        self.truth.textChanged.connect(self.update_missing)
        self.config.textChanged.connect(self.update_missing)
        c.polled.connect(self._polled)
        c.sessionChanged.connect(self._session_changed)
        c.busyChanged.connect(self._busy)
        self._connecting = False
        self._robot_fixed = False       # the station config names the robot
        self._resumed_folder = None     # the folder whose "Resume?" was answered Yes
        self._checked = None            # the session whose devices all answered once
        self._error: str | None = None
        self._robot_error: str | None = None
        if c.config_path and not c.simulate:
            self._robot_from_config(c.config_path)
        self._robot_changed()
        self.update_missing()

    # -- choices ---------------------------------------------------------------------
    def _rounds_toggled(self, on: bool) -> None:
        if self.rounds.isEnabled():
            self._rounds_wanted = on

    @property
    def locked(self) -> bool:
        """While a session is open (or opening) its robot, method, folder, truth, pose
        count and rounds are fixed: Disconnect to change them (what the page shows is
        what the session does)."""
        return self.controller.session is not None or self._connecting

    def _lock_choices(self) -> None:
        locked = self.locked
        for w in (self.method, self.count, self.truth_row, self.draw_truth_button):
            w.setEnabled(not locked and (w is not self.truth_row and w is not
                                         self.draw_truth_button or self.robot_file))
        self.robot.setEnabled(not locked and not self._robot_fixed)
        self.links_row.setEnabled(not locked and not self._robot_fixed)
        self.robot_file_button.setEnabled(not locked and not self._robot_fixed)
        self.folder_row.setEnabled(not locked)
        self._show_rounds()
        tip = ("Disconnect to change the robot, the method, the folder or the poses"
               if locked else "")
        for w in (self.robot, self.robot_file_button, self.method, self.folder_row, self.count,
                  self.rounds):
            w.setToolTip(tip or w.property("tip") or "")

    def _robot_from_config(self, path) -> None:
        try:
            robot = self.controller.robot_of_config(path)
        except Exception as e:  # noqa: BLE001 - said below
            self._error = f"The station config cannot be read: {error_text(e)}"
            return
        if is_robot_file(robot):
            robot = self.add_robot_file(robot)
        self.robot.setCurrentIndex(self.robot.findData(robot))
        self._robot_fixed = True
        self.robot.setEnabled(False)

    def browse_config(self) -> None:
        path, _ = QFileDialog.getOpenFileName(self, "Station config", self.config.text(),
                                              "Station config (*.toml);;All files (*)")
        if path:
            self.config.setText(path)
            self.controller.config_path = path
            self._error = None
            self._robot_from_config(path)
            self.update_missing()

    def browse_robot_file(self) -> None:
        path, _ = QFileDialog.getOpenFileName(self, "Robot file", str(ROBOT_FILES), URDF_FILTER)
        if path:
            self.robot.setCurrentIndex(self.robot.findData(self.add_robot_file(path)))

    def browse_truth(self) -> None:
        path, _ = QFileDialog.getOpenFileName(self, "Simulated truth", self.truth.text(),
                                              "Truth file (*.json);;All files (*)")
        if path:
            self.truth.setText(path)

    def browse_endpoints(self) -> None:
        path, _ = QFileDialog.getOpenFileName(self, "Simulator endpoints", "",
                                              "Endpoints (*.json);;All files (*)")
        if path:
            self.endpoints.setText(path)

    def browse_folder(self) -> None:
        path = QFileDialog.getExistingDirectory(self, "Session folder", self.folder.text())
        if path:
            self.folder.setText(path)

    # -- what is missing, in words -------------------------------------------------------
    def missing_items(self) -> list[str]:
        c, out = self.controller, []
        self.update_instrument()        # a URDF robot's (cached)
        if not c.simulate and not self.config.text().strip():
            out.append("No station config: choose the station's config file (Browse\u2026 "
                       "next to Station config), or start the station with --simulate.")
        if not self.folder.text().strip():
            out.append("No session folder: choose where the trace, the parameter file and "
                       "the report go (Browse\u2026 next to Session folder).")
        if c.simulate and self.robot_file and not self.truth.text().strip():
            out.append("No truth for the simulated arm: choose a truth file of the robot file "
                       "(Browse\u2026 next to Simulated truth), or press Draw one.")
        for error in (self._robot_error, self._station_error, self._error):
            if error:
                out.append(error)
        if c.session is None and not self._connecting and not out:
            out.append("Not connected: press Connect.")
        for name, ok in self.devices.states.items():
            if not ok:
                out.append(f"{name} does not answer: see its row under Devices (live) below "
                           "for what to check.")
        return out

    def update_missing(self, *_):
        if hasattr(self, "folder_row"):
            self._lock_choices()
        items = self.missing_items()
        if self._connecting:
            self.missing.setText("Connecting\u2026")
            self.missing.setStyleSheet("")
        elif items:
            self.missing.setText("\n".join(f"\u2022 {t}" for t in items))
            self.missing.setStyleSheet(f"color: {BAD_COLOR};")
        else:
            s = self.controller.session
            self.missing.setText(f"\u2713 Connected; session folder {s.out}"
                                 + (f" (resumed: {len(s.measured)} poses recorded)"
                                    if s.resumed else "") + ". Press Next. (To change the "
                                 "robot, the method or the folder: Disconnect first.)")
            self.missing.setStyleSheet(f"color: {OK_COLOR};")
        self.completeChanged.emit()

    def is_complete(self) -> bool:
        """Connected, and every device answered once (a device that fails later is
        said here and in the fault dialog, without locking the later steps)."""
        s = self.controller.session
        return bool(s is not None and self._checked is s)

    # -- connecting ----------------------------------------------------------------------
    def ask_resume(self, summary) -> bool:
        answer = QMessageBox.question(
            self, "Resume the session?",
            f"{summary.sentence()}.\n\nResume it? (No: choose another folder for a new "
            "session; the recorded poses stay where they are.)",
            QMessageBox.StandardButton.Yes | QMessageBox.StandardButton.No,
            QMessageBox.StandardButton.Yes)
        return answer == QMessageBox.StandardButton.Yes

    def connect_session(self) -> None:
        self._error = None
        if not self.folder.text().strip() or (not self.controller.simulate
                                               and not self.config.text().strip()):
            self.update_missing()
            return
        if self.controller.simulate and self.robot_file and not self.truth.text().strip():
            self.update_missing()
            return
        if self._robot_error or self._station_error:     # said in the list
            self.update_missing()
            return
        folder = Path(self.folder.text().strip()).expanduser()
        if folder.parent == sessions_root() and not folder.exists():
            # the wizard's own default place: made on the first Connect on a new machine
            try:
                folder.parent.mkdir(parents=True, exist_ok=True)
            except OSError as e:
                self._error = f"The folder {folder.parent} cannot be made: {e.strerror or e}"
                self.update_missing()
                return
        current = self.controller.session
        if current is not None and current.out.resolve() == folder.resolve():
            # this session's folder again (its devices were lost): connect anew, no question
            self._connecting = True
            self.devices.clear_devices()
            self.update_missing()
            self.controller.reopen(on_done=self._connected, on_error=self._failed)
            return
        summary = summarize_folder(folder)
        if summary is not None:
            if summary.error:
                self._error = summary.sentence() + ": choose another folder."
                self.update_missing()
                return
            # asked once per folder: a Connect again after a failed one does not ask again
            if self._resumed_folder != folder.resolve() and not self.ask_resume(summary):
                self._error = (f"{folder} holds a session you chose not to resume: choose "
                               "another folder for a new session.")
                self.update_missing()
                return
            self._resumed_folder = folder.resolve()
            robot = summary.robot
            if summary.robot_file:          # a robot file's session: the same file
                robot = self.robot_file_of(summary.robot_file)
                if robot is None:
                    self._error = (f"{folder} holds a session of the robot file "
                                   f"{summary.robot_file.get('name')}: choose that file "
                                   "(Robot file\u2026) first.")
                    self.update_missing()
                    return
                if summary.truth and self.controller.simulate:
                    self.truth.setText(summary.truth)
            self.set_choice(robot, summary.method)
        if self.controller.simulate:
            self.controller.truth_path = self.truth.text().strip() if self.robot_file else None
        else:
            self.controller.config_path = self.config.text().strip()
            self.controller.endpoints_path = self.endpoints.text().strip() or None
        request = PlanRequest(count=self.count.value() or None, grow=self.rounds.isChecked())
        self._connecting = True
        self.devices.clear_devices()
        self.update_missing()
        self.controller.open_session(robot=self.robot_key, method=self.method_name,
                                     out_dir=folder, request=request,
                                     on_done=self._connected, on_error=self._failed)

    def _connected(self, session) -> None:
        self._connecting = False
        self.controller.remember_folder(session.out)
        self.update_missing()

    def _failed(self, e) -> None:
        from drivers.check import hint_for

        self._connecting = False
        device = getattr(e, "device", None)
        self._error = (f"Could not connect: {error_text(e)}"
                       + (f" \u2014 {hint_for(device, self.controller.simulate)}." if device
                          else ""))
        self.update_missing()

    def disconnect_session(self) -> None:
        self.devices.clear_devices()
        self.controller.close_session(self.update_missing)

    def _polled(self, readings) -> None:
        self.devices.set_devices(readings)
        if readings and all(r.ok for r in readings):
            self._checked = self.controller.session
        self.update_missing()

    def _session_changed(self) -> None:
        self.update_missing()

    def _busy(self, busy: bool) -> None:
        self.connect_button.setEnabled(not busy)
        self.disconnect_button.setEnabled(not busy and self.controller.session is not None)
