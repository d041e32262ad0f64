"""Page 6, Export: the parameter file and the report, their checksum and where
they were written; the parameter file is read back and verified."""
from __future__ import annotations

from pathlib import Path

from PySide6.QtCore import Qt, QUrl
from PySide6.QtGui import QDesktopServices, QGuiApplication
from PySide6.QtWidgets import QFormLayout, QGroupBox, QHBoxLayout, QMessageBox, QPushButton

from station.gui.pages.base import Page, error_text
from station.gui.widgets import BAD_COLOR, OK_COLOR, note


class ExportPage(Page):
    title = "Export"
    subtitle = ("The calibrated parameters go into a parameter file the controller loads; the "
                "report documents the session. The checksum lets the controller check the "
                "file arrived unchanged.")

    def __init__(self, controller, parent=None):
        super().__init__(controller, parent)
        row = QHBoxLayout()
        self.export_button = QPushButton("&Write parameter file and report")
        self.export_button.setAutoDefault(False)
        self.export_button.clicked.connect(self.export)
        row.addWidget(self.export_button)
        row.addStretch(1)
        self.layout_.addLayout(row)
        box = QGroupBox("Written")
        form = QFormLayout(box)
        self.params = note("\u2013")
        self.report = note("\u2013")
        self.trace = note("\u2013")
        self.checksum = note("\u2013")
        self.urdf = note("\u2013")         # a robot file's arm: its calibration as a URDF
        self.checksum.setStyleSheet("font-family: 'DejaVu Sans Mono', monospace;")
        self.verified = note("")
        form.addRow("Parameter file:", self.params)
        form.addRow("Report:", self.report)
        form.addRow("Trace:", self.trace)
        form.addRow("URDF:", self.urdf)
        self.urdf_label = form.labelForField(self.urdf)
        form.addRow("Checksum:", self.checksum)
        form.addRow("Check:", self.verified)
        self.layout_.addWidget(box)
        row = QHBoxLayout()
        self.copy_button = QPushButton("Cop&y checksum")
        self.copy_button.clicked.connect(self.copy_checksum)
        self.folder_button = QPushButton("Open the f&older")
        self.folder_button.clicked.connect(lambda: self._open(self.files and
                                                              Path(self.files["params"]).parent))
        self.report_button = QPushButton("Open the re&port")
        self.report_button.clicked.connect(lambda: self._open(self.files and
                                                              self.files["report"]))
        for b in (self.copy_button, self.folder_button, self.report_button):
            b.setAutoDefault(False)
            b.setEnabled(False)
            row.addWidget(b)
        row.addStretch(1)
        self.layout_.addLayout(row)
        # what Open did: a desktop may accept the request and start nothing (no browser)
        self.opened = note("")
        self.opened.setTextInteractionFlags(Qt.TextInteractionFlag.TextSelectableByMouse)
        self.layout_.addWidget(self.opened)
        self.layout_.addWidget(note(
            "Load the parameter file into the robot controller; it holds every parameter with "
            "its standard deviation and identifiability, and the checksum above. "
            "\u2018python app.py params verify FILE\u2019 checks a copy."))
        self.layout_.addStretch(1)
        self.files: dict | None = None
        self.running = False
        self._show_urdf(False)
        controller.sessionChanged.connect(self._reset)

    def _reset(self) -> None:
        self.files = None
        for lab in (self.params, self.report, self.trace, self.checksum, self.urdf):
            lab.setText("\u2013")
        self._show_urdf(False)
        self.verified.setText("")

    def initialize_page(self) -> None:
        s = self.session
        if s is not None and s.outcome is not None and self.files is None and not self.running:
            self.export()

    def export(self) -> None:
        if self.session is None or self.running:
            return
        self.running = True
        self.export_button.setEnabled(False)
        self.verified.setText("Writing\u2026")

        def job(s):
            from station.outputs.params_file import read_params

            files = s.export()
            doc = read_params(files["params"])
            return files, doc

        self.controller.run(job, self._done, self._failed)

    def _done(self, result) -> None:
        files, doc = result
        self.running = False
        self.files = files
        self.export_button.setEnabled(True)
        self.params.setText(files["params"])
        self.report.setText(files["report"])
        self.trace.setText(files["trace"])
        self.checksum.setText(files["checksum"])
        self.urdf.setText(files.get("urdf") or "\u2013")
        self._show_urdf(bool(files.get("urdf")))
        n_id = sum(p["identifiable"] for p in doc["parameters"].values())
        self.verified.setText(f"\u2713 read back: {doc['format']} v{doc['version']}, robot "
                              f"{doc['robot']}, method {doc['method']}, {n_id} of "
                              f"{len(doc['parameters'])} parameters calibrated, checksum OK")
        self.verified.setStyleSheet(f"color: {OK_COLOR};")
        for b in (self.copy_button, self.folder_button, self.report_button):
            b.setEnabled(True)
        self.completeChanged.emit()

    def _show_urdf(self, shown: bool) -> None:
        self.urdf.setVisible(shown)
        self.urdf_label.setVisible(shown)

    def _failed(self, e) -> None:
        self.running = False
        self.export_button.setEnabled(True)
        self.verified.setText(f"Not written: {error_text(e)}")
        self.verified.setStyleSheet(f"color: {BAD_COLOR};")

    def copy_checksum(self) -> None:
        if self.files:
            QGuiApplication.clipboard().setText(self.files["checksum"])

    def _open(self, path) -> bool:
        """Open ``path`` with the desktop's program; where none starts, say where the
        file is (the path can be copied from the message)."""
        if not path:
            return False
        if QDesktopServices.openUrl(QUrl.fromLocalFile(str(path))):
            self.opened.setText(f"Asked the desktop to open {path}; if nothing opens, open "
                                "it yourself from there (the path can be selected and copied).")
            return True
        self.opened.setText(f"Not opened: no program could be started here. Open it yourself: "
                            f"{path}")
        box = QMessageBox(QMessageBox.Icon.Information, "Not opened",
                          f"No program could be started to open it here. Open it yourself:\n"
                          f"{path}", QMessageBox.StandardButton.Ok, self)
        box.setObjectName("notOpened")
        box.setTextInteractionFlags(Qt.TextInteractionFlag.TextSelectableByMouse)
        box.open()
        self.last_error = box
        return False

    def is_complete(self) -> bool:
        return self.files is not None
