"""Page 7, Offline: open a recorded trace, calibrate it in the GUI, save its
parameter file and report (no devices)."""
from __future__ import annotations

from pathlib import Path

from PySide6.QtWidgets import QFileDialog, QHBoxLayout, QPushButton

from station.gui.controller import iteration_sink
from station.gui.pages.base import Page, error_text
from station.gui.results import CalibrationView, validation_rows
from station.gui.widgets import BAD_COLOR, OK_COLOR, note


def one_line(text: str, limit: int = 200) -> str:
    """The first line of ``text``, at most ``limit`` characters."""
    first = text.strip().splitlines()[0] if text.strip() else ""
    return first if len(first) <= limit else first[: limit - 1] + "\u2026"


class OfflinePage(Page):
    title = "Offline: calibrate a recorded trace"
    subtitle = ("Open a trace recorded earlier (here or at another station), calibrate it and "
                "save its parameter file and report. No device is needed.")

    def __init__(self, controller, parent=None):
        super().__init__(controller, parent)
        row = QHBoxLayout()
        self.open_button = QPushButton("&Open trace\u2026")
        self.open_button.clicked.connect(self.browse)
        self.calibrate_button = QPushButton("&Calibrate")
        self.calibrate_button.clicked.connect(self.calibrate)
        self.save_button = QPushButton("&Save parameter file\u2026")
        self.save_button.clicked.connect(self.browse_save)
        self.report_button = QPushButton("Save &report\u2026")
        self.report_button.clicked.connect(self.browse_report)
        for b in (self.open_button, self.calibrate_button, self.save_button, self.report_button):
            b.setAutoDefault(False)
            row.addWidget(b)
        row.addStretch(1)
        self.layout_.addLayout(row)
        self.summary = note("No trace opened.")
        self.layout_.addWidget(self.summary)
        self.status = note("")
        self.layout_.addWidget(self.status)
        self.view = CalibrationView()
        self.layout_.addWidget(self.view)
        self.path: Path | None = None
        self.outcome = None
        self.validation = None
        self.saved: dict = {}
        self.running = False
        controller.offline.busyChanged.connect(lambda _: self._buttons())
        self._buttons()

    def _buttons(self) -> None:
        busy = self.controller.offline.busy
        self.calibrate_button.setEnabled(self.path is not None and not busy)
        self.save_button.setEnabled(self.outcome is not None and not busy)
        self.report_button.setEnabled(self.outcome is not None and not busy)

    def _say(self, text: str, color=None) -> None:
        self.status.setText(text)
        self.status.setStyleSheet(f"color: {color};" if color else "")

    # -- opening ------------------------------------------------------------------------------
    def browse(self) -> None:
        path, _ = QFileDialog.getOpenFileName(self, "Open a recorded trace", "",
                                              "Traces (*.jsonl);;All files (*)")
        if path:
            self.open_trace(path)

    def open_trace(self, path) -> bool:
        from station.recording.trace import read_trace

        # whatever happens, nothing of the previous trace stays on the page
        self.path, self.outcome, self.validation, self.saved = None, None, None, {}
        self.view.clear()
        self._say("")
        try:
            tr = read_trace(path)
        except Exception as e:  # noqa: BLE001 - said to the operator, in one line
            self.summary.setText(f"{Path(path).name} cannot be opened: "
                                 + one_line(error_text(e)).replace(f"{path}:", "line ", 1))
            self.summary.setToolTip(str(path))
            self.summary.setStyleSheet(f"color: {BAD_COLOR};")
            self._buttons()
            return False
        self.path = Path(path)
        ref = " with a reference" if tr.reference is not None else ""
        self.summary.setText(f"{path}: {tr.robot}, method {tr.method}, "
                             f"{len(tr.fit_poses)} poses to fit and {len(tr.validation_poses)} "
                             f"held out{ref}.")
        self.summary.setStyleSheet("")
        self.summary.setToolTip("")
        self._buttons()
        return True

    # -- calibrating ------------------------------------------------------------------------------
    def calibrate(self) -> None:
        if self.path is None or self.controller.offline.busy:
            return
        from station.fitting.batch import calibrate_trace

        path = str(self.path)
        self.view.clear()
        self._say("Calibrating\u2026")
        sink = iteration_sink(self.controller.iterated_offline)

        def job():
            outcome = calibrate_trace(path, callback=sink)
            return outcome, validation_rows(outcome)

        self.controller.offline.submit(job, self._done, self._failed)

    def _done(self, result) -> None:
        self.outcome, self.validation = result
        self.view.show_outcome(self.outcome, self.validation)
        self._say(f"\u2713 {self.outcome.result.message}", OK_COLOR)
        self._buttons()

    def _failed(self, e) -> None:
        if getattr(e, "outcome", None) is not None:   # failed the fit-quality gate: show it
            self.view.show_outcome(e.outcome, e.outcome.validation)
        self._say(f"The calibration failed: {error_text(e)}", BAD_COLOR)
        self._buttons()

    def add_iteration(self, it) -> None:
        self.view.add_iteration(it)

    # -- saving ---------------------------------------------------------------------------------
    def browse_save(self) -> None:
        start = str(self.path.with_name("params.json")) if self.path else ""
        path, _ = QFileDialog.getSaveFileName(self, "Save the parameter file", start,
                                              "Parameter files (*.json)")
        if path:
            self.save_params(path)

    def browse_report(self) -> None:
        start = str(self.path.with_name("report.html")) if self.path else ""
        path, _ = QFileDialog.getSaveFileName(self, "Save the report", start, "HTML (*.html)")
        if path:
            self.save_report(path)

    def save_params(self, path) -> dict | None:
        from station.outputs.fit_summary import outcome_document
        from station.outputs.params_file import write_params

        try:
            doc = write_params(path, outcome_document(self.outcome, str(self.path)))
        except Exception as e:  # noqa: BLE001 - said to the operator
            self._say(f"The parameter file was not written: {error_text(e)}", BAD_COLOR)
            return None
        self.saved["params"] = str(path)
        self._say(f"\u2713 Parameter file written to {path} ({doc['checksum']})", OK_COLOR)
        return doc

    def save_report(self, path) -> None:
        """Write the report on the worker (its figures take a moment)."""
        from station.outputs.report import write_report

        outcome, validation = self.outcome, self.validation
        self._say("Writing the report\u2026")

        def done(_):
            self.saved["report"] = str(path)
            self._say(f"\u2713 Report written to {path}", OK_COLOR)

        self.controller.offline.submit(
            lambda: write_report(path, outcome, validation=validation), done,
            lambda e: self._say(f"The report was not written: {error_text(e)}", BAD_COLOR))
