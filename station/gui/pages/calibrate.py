"""Page 5, Calibrate: Algorithm 2 on the recorded poses with live plots, then
the identifiability table (report Table 3) and the validation errors."""
from __future__ import annotations

from PySide6.QtWidgets import QHBoxLayout, QPushButton

from station.gui.pages.base import Page, error_text
from station.gui.results import CalibrationView
from station.gui.widgets import BAD_COLOR, OK_COLOR, note


class CalibratePage(Page):
    title = "Calibrate"
    subtitle = ("The parameters are fitted to the recorded poses (linearized iterative least "
                "squares, report Algorithm 2). The plots fill while it iterates; then each "
                "parameter is shown with its uncertainty and whether the measurements "
                "determine it, and the held-out poses show the errors before and after.")

    def __init__(self, controller, parent=None):
        super().__init__(controller, parent)
        row = QHBoxLayout()
        self.calibrate_button = QPushButton("&Calibrate")
        self.calibrate_button.setAutoDefault(False)
        self.calibrate_button.clicked.connect(self.calibrate)
        row.addWidget(self.calibrate_button)
        self.status = note("")
        row.addWidget(self.status, 1)
        self.layout_.addLayout(row)
        self.view = CalibrationView()
        self.layout_.addWidget(self.view)
        self.running = False
        self.iterations = 0
        controller.iterated.connect(self._iteration)
        controller.sessionChanged.connect(self._session_changed)

    def initialize_page(self) -> None:
        s = self.session
        if s is None:
            return
        if s.outcome is None and not self.running:
            self.calibrate()

    def _session_changed(self) -> None:
        self.view.clear()

    def calibrate(self) -> None:
        if self.session is None or self.running:
            return
        self.running = True
        self.iterations = 0
        self.view.clear()
        self.calibrate_button.setEnabled(False)
        self.status.setText("Calibrating\u2026")
        self.status.setStyleSheet("")
        self.completeChanged.emit()
        self.controller.calibrate(self._done, self._failed)

    def _iteration(self, it) -> None:
        if self.running:
            self.iterations += 1
            self.status.setText(f"Calibrating\u2026 iteration {self.iterations}, cost "
                                f"{it.cost:.4g}, condition number {it.condition_number:.4g}")
            self.view.add_iteration(it)

    def _done(self, result) -> None:
        outcome, validation = result
        self.running = False
        self.calibrate_button.setEnabled(True)
        self.view.show_outcome(outcome, validation)
        self.status.setText(f"\u2713 {outcome.result.message}. Press Next to write the "
                            "parameter file.")
        self.status.setStyleSheet(f"color: {OK_COLOR};")
        self.completeChanged.emit()

    def _failed(self, e) -> None:
        self.running = False
        self.calibrate_button.setEnabled(True)
        if getattr(e, "outcome", None) is not None:   # failed the fit-quality gate: show it
            self.view.show_outcome(e.outcome, e.outcome.validation)
        self.status.setText(f"The calibration failed: {error_text(e)}")
        self.status.setStyleSheet(f"color: {BAD_COLOR};")
        self.completeChanged.emit()

    def is_complete(self) -> bool:
        s = self.session
        return bool(s is not None and s.outcome is not None and not self.running)
