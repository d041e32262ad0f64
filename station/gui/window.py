"""The main window: the steps on the left, the page, Back / Next below.

A step can be opened once every step before it is complete; the Offline page
(a recorded trace) is always open. Closing the window stops measuring after
the current pose (the trace holds every recorded pose), closes the devices and
stops the simulator; the next start offers to resume an unfinished session.
"""
from __future__ import annotations

from pathlib import Path

from PySide6.QtCore import QSize, Qt, QTimer, QUrl
from PySide6.QtGui import QAction, QDesktopServices, QFont, QGuiApplication, QKeySequence
from PySide6.QtWidgets import (QHBoxLayout, QLabel, QListWidget, QListWidgetItem, QMainWindow,
                               QMessageBox, QPushButton, QStackedWidget, QVBoxLayout, QWidget)

from station.gui.controller import Controller, summarize_folder
from station.gui.widgets import WARN_COLOR
from station.gui.pages import TITLES, PageId
from station.gui.pages.accuracy import AccuracyPage
from station.gui.pages.calibrate import CalibratePage
from station.gui.pages.execute import ExecutePage
from station.gui.pages.export import ExportPage
from station.gui.pages.offline import OfflinePage
from station.gui.pages.plan import PlanPage
from station.gui.pages.reference import ReferencePage
from station.gui.pages.setup import SetupPage

DOCS = Path(__file__).resolve().parents[2] / "docs"
GUIDE = ("1 Setup: choose the robot (AGEBOT, a robot file, or a URDF with the base and tip "
         "links of the chain to calibrate) and the method, a session folder, "
         "then Connect; what is missing is listed above the Connect button.\n"
         "2 Reference: jog the robot to the suggested point (or press Go to), attach the "
         "draw-wire there and Capture: a small test move checks the sensors first (a URDF "
         "robot measured by a motion capture has no reference: check it sees the markers).\n"
         "3 Plan: the poses to measure; regenerate or edit them before measuring.\n"
         "4 Execute: Start measuring; every pose is in the trace at once, so closing loses "
         "none and reopening the folder resumes.\n"
         "5 Calibrate: the parameters with their std and identifiability, the held-out "
         "poses before and after.\n"
         "6 Export: the parameter file for the controller and the report.\n"
         "7 Accuracy: ISO 9283's pose accuracy and repeatability before and after the "
         "calibration, measured by the motion capture (a URDF robot's sm-markers session; "
         "skip it otherwise).\n\n"
         "Numbers are shown in mm and degrees; u is the actuator unit of qm (the drives' "
         "position unit). More: README.md and docs/ (Help > Documentation).")
#: session events kept above the page until dismissed (the rest: the status bar, the log)
NOTICE_KINDS = ("warning", "fault", "lost", "abort", "envelope", "fit-quality", "outlier",
                "remeasure-failed", "stop")
MAX_NOTICES = 3
PREFERRED = (1440, 900)        # the window's size where the screen has room for it
PAGES = {PageId.SETUP: SetupPage, PageId.REFERENCE: ReferencePage, PageId.PLAN: PlanPage,
         PageId.EXECUTE: ExecutePage, PageId.CALIBRATE: CalibratePage,
         PageId.EXPORT: ExportPage, PageId.ACCURACY: AccuracyPage,
         PageId.OFFLINE: OfflinePage}
WIZARD = [p for p in PageId if p != PageId.OFFLINE]


class MainWindow(QMainWindow):
    def __init__(self, controller: Controller, parent=None):
        super().__init__(parent)
        self.controller = controller
        self.setWindowTitle("Calibration station" + (" (simulated devices)"
                                                     if controller.simulate else ""))
        f = QFont(self.font())
        f.setPointSizeF(max(f.pointSizeF(), 10.0))
        self.setFont(f)
        self.pages = {pid: cls(controller) for pid, cls in PAGES.items()}
        self.stack = QStackedWidget()
        for pid in PageId:
            self.stack.addWidget(self.pages[pid])
        self.steps = QListWidget()
        self.steps.setFixedWidth(210)
        self.steps.setAccessibleName("steps")
        for pid in PageId:
            item = QListWidgetItem(TITLES[pid])
            item.setData(Qt.ItemDataRole.UserRole, int(pid))
            item.setSizeHint(QSize(200, 34))
            self.steps.addItem(item)
        self.steps.currentRowChanged.connect(self._step_clicked)
        self.back_button = QPushButton("< &Back")
        self.next_button = QPushButton("&Next >")
        self.next_button.setDefault(True)
        self.back_button.clicked.connect(self.back)
        self.next_button.clicked.connect(self.next)
        self.busy = QLabel("")
        nav = QHBoxLayout()
        nav.addWidget(self.busy, 1)
        nav.addWidget(self.back_button)
        nav.addWidget(self.next_button)
        # what the operator must read (a warning, a fault, a lost zero), kept above the
        # page until dismissed: the status bar shows only the start of a long line
        self.notice = QLabel("")
        self.notice.setObjectName("notice")
        self.notice.setWordWrap(True)
        self.notice.setStyleSheet(f"color: {WARN_COLOR}; border: 1px solid {WARN_COLOR}; "
                                  "padding: 4px;")
        self.notice.setVisible(False)
        self.dismiss_button = QPushButton("Dis&miss")
        self.dismiss_button.setAutoDefault(False)
        self.dismiss_button.clicked.connect(self.clear_notices)
        self.dismiss_button.setVisible(False)
        notices = QHBoxLayout()
        notices.addWidget(self.notice, 1)
        notices.addWidget(self.dismiss_button, 0, Qt.AlignmentFlag.AlignTop)
        self._notices: list[str] = []
        right = QVBoxLayout()
        right.addLayout(notices)
        right.addWidget(self.stack, 1)
        right.addLayout(nav)
        central = QWidget()
        lay = QHBoxLayout(central)
        lay.addWidget(self.steps)
        lay.addLayout(right, 1)
        self.setCentralWidget(central)
        self._menus()
        for page in self.pages.values():
            page.completeChanged.connect(self._update_nav)
        controller.busyChanged.connect(self._busy)
        controller.eventLogged.connect(self._event)
        controller.sessionChanged.connect(self._update_nav)
        controller.iterated_offline.connect(self.pages[PageId.OFFLINE].add_iteration)
        self.current = PageId.SETUP
        self.resize(*PREFERRED)
        self._update_nav()

    def show_fitted(self) -> None:
        """Show the window sized to its screen; fitted again once the window manager
        has framed it (the frame's size is known only then)."""
        self.fit_to_screen()
        self.show()
        for ms in (200, 700, 1500, 3000):     # the frame is known once the manager framed it
            QTimer.singleShot(ms, self.fit_to_screen)

    def fit_to_screen(self) -> None:
        """Size the window to the screen it opens on: the available geometry (without
        panels and docks) less the window manager's frame, at most :data:`PREFERRED`."""
        screen = self.screen() or QGuiApplication.primaryScreen()
        if screen is None or self.isMaximized() or self.isFullScreen():
            return
        avail = screen.availableGeometry()
        fw = max(0, self.frameGeometry().width() - self.geometry().width())
        fh = max(0, self.frameGeometry().height() - self.geometry().height())
        w = min(PREFERRED[0], avail.width() - fw)
        h = min(PREFERRED[1], avail.height() - fh)
        self.resize(max(w, 640), max(h, 480))
        self.move(avail.left() + max(0, (avail.width() - w - fw) // 2),
                  avail.top() + max(0, (avail.height() - h - fh) // 2))

    def _menus(self) -> None:
        m = self.menuBar().addMenu("&File")
        a = QAction("&New session", self)
        a.setShortcut(QKeySequence.StandardKey.New)
        a.triggered.connect(self.new_session)
        m.addAction(a)
        a = QAction("&Open a recorded trace\u2026", self)
        a.setShortcut(QKeySequence.StandardKey.Open)
        a.triggered.connect(self.open_trace)
        m.addAction(a)
        m.addSeparator()
        a = QAction("&Quit", self)
        a.setShortcut(QKeySequence.StandardKey.Quit)
        a.triggered.connect(self.close)
        m.addAction(a)
        m = self.menuBar().addMenu("&Help")
        a = QAction("&Getting started", self)
        a.setShortcut(QKeySequence.StandardKey.HelpContents)
        a.triggered.connect(lambda: QMessageBox.information(self, "Getting started", GUIDE))
        m.addAction(a)
        a = QAction("&Documentation (README, docs/)", self)
        a.triggered.connect(lambda: QDesktopServices.openUrl(QUrl.fromLocalFile(str(DOCS))))
        m.addAction(a)
        a = QAction("&About", self)
        a.triggered.connect(lambda: QMessageBox.about(
            self, "Calibration station",
            "Robot calibration station: reference, IK-planned poses, Algorithm 2 calibration "
            "with identifiability, parameter file and report."))
        m.addAction(a)

    # -- navigation ---------------------------------------------------------------------------
    def page(self, pid: PageId):
        return self.pages[PageId(pid)]

    def reachable(self, pid: PageId) -> bool:
        if pid == PageId.OFFLINE:
            return True
        return all(self.pages[p].is_complete() for p in WIZARD if p < pid)

    def go_to(self, pid: PageId) -> bool:
        pid = PageId(pid)
        if not self.reachable(pid):
            return False
        if pid != self.current:
            self.pages[self.current].leave_page()
        self.current = pid
        self.stack.setCurrentWidget(self.pages[pid])
        self.steps.blockSignals(True)
        self.steps.setCurrentRow(int(pid))
        self.steps.blockSignals(False)
        self.pages[pid].initialize_page()
        self._update_nav()
        return True

    def next(self) -> None:
        if self.current in WIZARD and self.current != WIZARD[-1]:
            self.go_to(PageId(self.current + 1))

    def back(self) -> None:
        if self.current == PageId.OFFLINE:
            self.go_to(PageId.SETUP)
        elif self.current > PageId.SETUP:
            self.go_to(PageId(self.current - 1))

    def _step_clicked(self, row: int) -> None:
        if row >= 0 and not self.go_to(PageId(row)):
            self.steps.blockSignals(True)
            self.steps.setCurrentRow(int(self.current))
            self.steps.blockSignals(False)

    def _update_nav(self) -> None:
        for pid in PageId:
            item = self.steps.item(int(pid))
            ok = self.reachable(pid)
            flags = item.flags()
            item.setFlags(flags | Qt.ItemFlag.ItemIsEnabled if ok
                          else flags & ~Qt.ItemFlag.ItemIsEnabled)
            done = pid in WIZARD and self.pages[pid].is_complete() and pid != self.current
            item.setText(("\u2713 " if done else "   ") + TITLES[pid])
        cur = self.current
        self.back_button.setEnabled(cur != PageId.SETUP)
        self.next_button.setEnabled(cur in WIZARD and cur != WIZARD[-1]
                                    and self.pages[cur].is_complete())

    def new_session(self) -> None:
        """A new session in a new folder: the open one is closed (its trace keeps every
        recorded pose), the setup page is shown with a fresh folder."""
        from station.gui.pages.setup import default_folder

        if self.pages[PageId.EXECUTE].running or self.pages[PageId.ACCURACY].running:
            QMessageBox.information(self, "New session", "Poses are being measured: abort "
                                    "(or let it finish) first.")
            return
        setup = self.pages[PageId.SETUP]

        def fresh():
            self.clear_notices()
            setup.devices.clear_devices()
            setup.folder.setText(default_folder())
            setup.update_missing()
            self.go_to(PageId.SETUP)

        if self.controller.session is not None:
            self.controller.close_session(fresh)
        else:
            fresh()

    def open_trace(self) -> None:
        self.go_to(PageId.OFFLINE)
        self.pages[PageId.OFFLINE].browse()

    # -- status -------------------------------------------------------------------------------
    def _busy(self, busy: bool) -> None:
        self.busy.setText("Working\u2026" if busy else "")

    def _event(self, ev: dict) -> None:
        text = f"{ev.get('kind')}: {ev.get('message', '')}"
        self.statusBar().showMessage(text, 15000)
        self.statusBar().setToolTip(text)
        if ev.get("kind") in NOTICE_KINDS:
            self._notices = [t for t in self._notices if t != text][-(MAX_NOTICES - 1):] + [text]
            self.notice.setText("\n".join(self._notices))
            self.notice.setVisible(True)
            self.dismiss_button.setVisible(True)

    def clear_notices(self) -> None:
        self._notices = []
        self.notice.setText("")
        self.notice.setVisible(False)
        self.dismiss_button.setVisible(False)

    # -- resume and close ---------------------------------------------------------------------
    def offer_resume(self) -> bool:
        """At start: the last session folder holds an unfinished session -> offer it."""
        folder = self.controller.last_folder()
        summary = summarize_folder(folder) if folder else None
        if summary is None or not summary.unfinished:
            return False
        setup = self.pages[PageId.SETUP]
        setup.folder.setText(str(summary.folder))
        if summary.robot_file is None:  # a robot file's: found by connect_session
            setup.set_choice(summary.robot, summary.method)
        setup.connect_session()         # asks "Resume the session?"
        return True

    def closeEvent(self, event) -> None:
        execute = self.pages[PageId.EXECUTE]
        if execute.running and not self.controller.closed:
            # the robot stops after the current pose while the question is open
            s = self.controller.session
            was_paused = bool(s is not None and s.paused)
            if s is not None and not was_paused:
                execute.pause()
            answer = QMessageBox.question(
                self, "Stop measuring?",
                "Measuring is paused after the current pose. Stop and close? Every "
                "recorded pose is kept; open the same session folder again to continue. "
                "(No: measuring goes on.)",
                QMessageBox.StandardButton.Yes | QMessageBox.StandardButton.No,
                QMessageBox.StandardButton.No)
            if answer != QMessageBox.StandardButton.Yes:
                if s is not None and not was_paused and execute.running:
                    execute.resume()
                event.ignore()
                return
        if execute.fault_box is not None:
            execute.fault_box.close()
        self.pages[PageId.ACCURACY].shut_down()     # a test stops before its next move
        self.busy.setText("Closing: stopping after the current pose\u2026")
        self.controller.shutdown()
        event.accept()

