"""Page 7, Accuracy: ISO 9283's pose accuracy AP and repeatability RP, before and after
the calibration, measured by the station's motion capture (docs/accuracy.md). The test
``app.py accuracy`` runs (:mod:`station.session.iso_test`) on the session's devices, of
the parameter file the Export step wrote: the operator chooses the cycles, starts it,
follows it (the program, cycle k of n, the pose), can stop it; a device fault asks Retry /
Skip the cycle / Abort as on the Execute page. Then the table before and after and the
factor; ``accuracy.csv`` and ``accuracy.html`` are in the session folder, the page linked
from its report. A test that stops writes nothing. A session whose instrument gives no
point (a draw-wire, an inclinometer) says in one line why the test does not apply."""
from __future__ import annotations

import contextlib

import math
import threading

from PySide6.QtCore import QUrl, Signal
from PySide6.QtGui import QDesktopServices
from PySide6.QtWidgets import (QGroupBox, QHBoxLayout, QLabel, QListWidget, QMessageBox,
                               QProgressBar, QPushButton, QSpinBox, QTableWidgetItem,
                               QVBoxLayout, QWidget)

from calibration import iso9283
from station.gui import fault_dialog
from station.gui.pages.base import Page, error_text
from station.gui.tables import ContentTable
from station.gui.widgets import BAD_COLOR, OK_COLOR, WARN_COLOR, note
from station.gui.worker import FaultQuestion
from station.outputs.iso9283 import MAX_CYCLES, why_not
from station.session.folder import PARAMS

CSV, PAGE = "accuracy.csv", "accuracy.html"
POSITION = ("pose", "AP_P before [mm]", "AP_P after [mm]", "before / after", "RP_l before [mm]",
            "RP_l after [mm]", "predicted after [mm]")
ORIENTATION = ("pose", "AP_a, b, c before [\u00b0]", "after [\u00b0]",
               "RP_a, b, c before [\u00b1\u00b0]", "after [\u00b1\u00b0]")


class AccuracyPage(Page):
    title = "Accuracy test (ISO 9283)"
    subtitle = ("How close the robot comes to the poses it is programmed to, and how closely it "
                "comes back: the test cube's five poses, n cycles with the nominal program "
                "(before the calibration) and n with the compensated program (after), measured "
                "by the motion capture. It tests the parameter file of the Export step; the "
                "CSV and the page go into the session folder. The step can be skipped.")

    said = Signal(str)               # a line of the test (worker thread -> GUI)
    posed = Signal(object)           # station.session.iso_run.Where, before each move

    def __init__(self, controller, parent=None):
        super().__init__(controller, parent)
        self.why = note("", WARN_COLOR)
        self.layout_.addWidget(self.why)
        self.test = QWidget()          # what the test shows (hidden where it does not apply)
        lay = QVBoxLayout(self.test)
        lay.setContentsMargins(0, 0, 0, 0)
        row = QHBoxLayout()
        row.addWidget(QLabel("C&ycles of each program:"))
        self.cycles = QSpinBox()
        self.cycles.setRange(2, MAX_CYCLES)
        self.cycles.setValue(iso9283.CYCLES)
        self.cycles.valueChanged.connect(self._cycles_changed)
        row.itemAt(0).widget().setBuddy(self.cycles)
        row.addWidget(self.cycles)
        self.start_button = QPushButton("&Start the test")
        self.stop_button = QPushButton("S&top")
        for b, slot in ((self.start_button, self.start), (self.stop_button, self.stop)):
            b.setAutoDefault(False)
            b.clicked.connect(slot)
            row.addWidget(b)
        self.cycles_note = note("")
        row.addWidget(self.cycles_note, 1)
        lay.addLayout(row)
        self.progress = QProgressBar()
        self.progress.setFormat("%v of %m poses")
        lay.addWidget(self.progress)
        self.current = note("")
        lay.addWidget(self.current)
        self.log = QListWidget()
        self.log.setFixedHeight(96)
        lay.addWidget(self.log)
        box = QGroupBox("AP and RP before and after the calibration")
        inner = QVBoxLayout(box)
        self.table = ContentTable(6, len(POSITION))
        self.orientation = ContentTable(5, len(ORIENTATION))
        for t, head in ((self.table, POSITION), (self.orientation, ORIENTATION)):
            t.setHorizontalHeaderLabels(list(head))
            t.verticalHeader().setVisible(False)
            t.setEditTriggers(ContentTable.EditTrigger.NoEditTriggers)
            inner.addWidget(t)
        self.summary = note("")
        inner.addWidget(self.summary)
        lay.addWidget(box)
        self.results_box = box
        row = QHBoxLayout()
        self.written = note("")
        row.addWidget(self.written, 1)
        self.open_button = QPushButton("Open the &page")
        self.open_button.setAutoDefault(False)
        self.open_button.clicked.connect(self.open_page)
        row.addWidget(self.open_button)
        lay.addLayout(row)
        self.layout_.addWidget(self.test)
        self.status = note("")
        self.layout_.addWidget(self.status)
        self.layout_.addStretch(1)
        self.faults = FaultQuestion(self)
        self.faults.asked.connect(self.ask_fault)
        self.said.connect(self._said)
        self.posed.connect(self._posed)
        self.running = False
        self.figures = None
        self.fault_box: QMessageBox | None = None
        self._stop = threading.Event()
        self._csv_written = False
        self._lines: list[str] = []
        controller.sessionChanged.connect(self._reset)
        self._reset()

    # -- the page's state ----------------------------------------------------------------------
    def _reset(self) -> None:
        if self.running:
            return
        self.figures = None
        self.log.clear()
        self.current.setText("")
        self.written.setText("")
        self.status.setText("")
        self.progress.setValue(0)
        self.results_box.setVisible(False)
        self._cycles_changed()
        self._buttons()

    def not_applicable(self) -> str | None:
        """Why the test does not apply to this session's instrument (one line), or None."""
        s = self.session
        if s is None:
            return None
        urdf = {"urdf": True} if hasattr(s.robot, "calibrated_origins") else {}
        if why_not({"method": s.method, **urdf}) is None:
            return None
        return ("The test does not apply here: it needs the tool's three coordinates from a "
                "point instrument (a motion capture measuring a URDF robot, sm-markers); this "
                f"session's {s.method} reads the station's own sensors, a draw-wire's one "
                "distance and an inclinometer's angles (docs/accuracy.md). Skip this step.")

    def applies(self) -> str | None:
        """Why the test cannot be started now (one line), or None."""
        s = self.session
        if s is None:
            return "No session: connect one on the Setup step."
        why = self.not_applicable()
        if why:
            return why
        if not (s.out / PARAMS).is_file():
            return "The test needs the session's parameter file: write it on the Export step."
        return None

    def initialize_page(self) -> None:
        why = self.applies() if not self.running else None
        self.why.setText(why or "")
        self.why.setVisible(bool(why))
        self.test.setVisible(self.not_applicable() is None)
        s = self.session
        if s is not None and why is None and self.figures is None and not self.running \
                and (s.out / CSV).is_file():
            self.written.setText(f"An earlier test's {CSV} and {PAGE} are in the session "
                                 "folder; Start replaces them.")
        self._buttons()

    def _buttons(self) -> None:
        ok = self.session is not None and self.applies() is None
        for w in (self.cycles, self.start_button):
            w.setEnabled(ok and not self.running)
        self.stop_button.setEnabled(self.running)
        self.open_button.setEnabled(self.figures is not None and not self.running)
        self.completeChanged.emit()

    def is_complete(self) -> bool:
        return not self.running and (self.figures is not None
                                     or self.not_applicable() is not None)

    def _cycles_changed(self) -> None:
        n = self.cycles.value()
        self.cycles_note.setText(
            "" if n >= iso9283.CYCLES else
            f"fewer than the standard's {iso9283.CYCLES}: RP's S_l from {n} values (about "
            f"{1 / math.sqrt(2 * (n - 1)):.0%} uncertain)")

    # -- the test --------------------------------------------------------------------------------
    def start(self) -> None:
        s = self.session
        if s is None or self.running or self.applies() is not None:
            return
        cycles = self.cycles.value()
        self.running, self.figures, self._csv_written = True, None, False
        self._stop.clear()
        self.faults.reopen()
        self.log.clear()
        self._lines = []
        self.results_box.setVisible(False)
        self.written.setText("")
        self.progress.setMaximum(2 * 5 * cycles)
        self.progress.setValue(0)
        self.status.setText("Finding the test cube\u2026")
        self.status.setStyleSheet("")
        self._buttons()
        params, out, page = s.out / PARAMS, s.out / CSV, s.out / PAGE
        config, rig = s.config, s.rig

        def job(_s):
            from drivers.atomic import check_outputs
            from station.outputs.params_file import check_usable, read_params
            from station.session import iso_test

            check_outputs((str(out), "the accuracy CSV"), (str(page), "the test's page"),
                          inputs=(str(params),))
            doc = read_params(params)
            check_usable(doc, str(params))
            plan = iso_test.plan(doc, str(params), config, None, 0, self.said.emit)
            with fresh_noise(self.controller):
                readings = iso_test.measure(rig, config, plan, cycles, say=self.said.emit,
                                            on_pose=self.posed.emit, stop=self._stop.is_set,
                                            fault_policy=self.faults)
            return iso_test.write(plan, readings, str(out), str(page), self.said.emit)

        self.controller.run(job, self._done, self._failed)

    def stop(self) -> None:
        if self.running:
            self._stop.set()
            self.status.setText("Stopping before the next move\u2026 nothing will be written.")

    def shut_down(self) -> None:
        """The window closes: stop before the next move, answer an open question Abort."""
        self._stop.set()
        self.faults.cancel_all()
        if self.fault_box is not None:
            self.fault_box.close()

    def _said(self, text: str) -> None:
        self._lines.append(text)
        if text.startswith("every measured cycle written"):
            self._csv_written = True
        self.log.addItem(text)
        self.log.scrollToBottom()

    def _posed(self, where) -> None:
        cycles = where.cycles
        done = (0 if where.program == "nominal" else 5 * cycles) + 5 * (where.cycle - 1) \
            + iso9283.CYCLE.index(where.pose)
        self.progress.setValue(done)
        self.status.setText("Measuring\u2026 Stop ends the test before the next move.")
        self.current.setText(f"The {where.program} program"
                             f" ({'before' if where.program == 'nominal' else 'after'} the "
                             f"calibration): cycle {where.cycle} of {cycles}, to {where.pose}")

    def _done(self, figures) -> None:
        from station.outputs.iso9283 import summary

        self.running, self.figures = False, figures
        self.progress.setValue(self.progress.maximum())
        self.current.setText("")
        self._show(figures)
        self.summary.setText("\n".join(summary(figures.res, figures.cycles,
                                               figures.predicted_rms)))
        link = [t[len("the page: "):] for t in self._lines if t.startswith("the page: ")]
        s = self.session
        self.written.setText(f"Written: {s.out / CSV} (every measured cycle) and {s.out / PAGE} "
                             f"(the test's page){'; ' + link[-1] if link else ''}.")
        self.status.setText(f"\u2713 AP_P {figures.rms('nominal') * 1e3:.3f} mm before, "
                            f"{figures.rms('compensated') * 1e3:.3f} mm after: "
                            f"{figures.factor:.1f} times closer.")
        self.status.setStyleSheet(f"color: {OK_COLOR};")
        self._buttons()

    def _failed(self, e) -> None:
        from station.session.iso_run import TestStopped

        self.running = False
        self.current.setText("")
        kept = (f" The measurements are in {self.session.out / CSV}; the page can be written "
                "again with app.py accuracy --csv." if self._csv_written and
                self.session is not None else " Nothing was written.")
        if isinstance(e, TestStopped):       # "stopped before P4 of cycle 1 ..."
            self.status.setText(f"The test {error_text(e)}. Start runs it again.")
        else:
            self.status.setText(f"The test stopped: {error_text(e)}.{kept}")
        self.status.setStyleSheet(f"color: {BAD_COLOR};")
        self._buttons()

    def _show(self, f) -> None:
        for t, rows in ((self.table, position_rows(f)), (self.orientation,
                                                         orientation_rows(f))):
            t.setRowCount(len(rows))
            for r, cells in enumerate(rows):
                for c, text in enumerate(cells):
                    t.setItem(r, c, QTableWidgetItem(text))
            t.resizeColumnsToContents()
            t.fit()
        self.orientation.setVisible(f.orientation)
        self.results_box.setVisible(True)

    # -- a device fault: Retry / Skip the cycle / Abort --------------------------------------------
    def ask_fault(self, request) -> None:
        where = request.pose
        fault_dialog.ask(
            self, request, self.faults.answer, name="accuracyFault",
            text=f"{where} could not be measured (attempt {request.attempt + 1}).",
            informative=(
                f"{error_text(request.error)}\n\nRetry: the devices recovered, the pose "
                f"approached again from the one before it.\nSkip the cycle: leave the rest "
                f"of cycle {where.cycle} out of the figures and go on with the next.\n"
                "Abort: stop the test; nothing is written."),
            skip_label="S&kip the cycle")

    def open_page(self) -> None:
        s = self.session
        if s is not None and self.figures is not None:
            QDesktopServices.openUrl(QUrl.fromLocalFile(str(s.out / PAGE)))


def position_rows(f) -> list[list[str]]:
    """The position table's cells (mm, as printed) of the test's figures ``f``: per pose
    AP_P and RP_l before and after, the factor, the predicted std; then the mean (AP,
    RP) and the factor of the RMS."""
    rows = [[b.name, f"{b.ap * 1e3:.3f}", f"{a.ap * 1e3:.3f}", f"{b.ap / max(a.ap, 1e-12):.1f}",
             f"{b.rp * 1e3:.3f}", f"{a.rp * 1e3:.3f}",
             f"{p * 1e3:.3f}" if math.isfinite(p) else "\u2013"]
            for b, a, p in zip(f.res["nominal"], f.res["compensated"], f.predicted)]
    mean = [sum(getattr(x, k) for x in f.res[prog]) / 5 * 1e3
            for k, prog in (("ap", "nominal"), ("ap", "compensated"), ("rp", "nominal"),
                            ("rp", "compensated"))]
    rows.append(["mean", f"{mean[0]:.3f}", f"{mean[1]:.3f}", f"{f.factor:.1f} (RMS)",
                 f"{mean[2]:.3f}", f"{mean[3]:.3f}",
                 f"{f.predicted_rms * 1e3:.3f} (RMS)" if f.predicted_rms is not None
                 else "\u2013"])
    return rows


def orientation_rows(f) -> list[list[str]]:
    """The orientation table's cells (degrees, as printed), none where not measured."""
    if not f.orientation:
        return []
    return [[b.name, *(", ".join(f"{math.degrees(v):+.4f}" for v in x.ap_abc) for x in (b, a)),
             *(", ".join(f"{math.degrees(v):.4f}" for v in x.rp_abc) for x in (b, a))]
            for b, a in zip(f.res["nominal"], f.res["compensated"])]


@contextlib.contextmanager
def fresh_noise(controller):
    """A simulated station reads a pose's noise as a function of the pose (a resumed
    session reads what it read before); the test reads each pose many times, as a real
    instrument does: fresh noise per reading while it runs."""
    sim = getattr(controller, "sim", None) if getattr(controller, "simulate", False) else None
    if sim is None or not sim.alive:
        yield
        return
    ctl = sim.control()
    try:
        ctl.call(pose_noise=False)
        yield
    finally:
        try:
            ctl.call(pose_noise=True)
        except (OSError, RuntimeError, ConnectionError):
            pass           # the simulator went away: the next session starts a new one
        ctl.close()
