"""What every page has: a title, a one-line purpose, a scrolling body, and the
wizard protocol (``initialize_page``, ``is_complete``, ``completeChanged``)."""
from __future__ import annotations

from PySide6.QtCore import Signal
from PySide6.QtWidgets import QLabel, QMessageBox, QVBoxLayout, QWidget

from station.gui.widgets import heading, scrolled


def error_text(e: BaseException) -> str:
    """One line for the operator (StationError messages are written for them)."""
    from calibration.errors import StationError

    if isinstance(e, StationError):
        from station.gui.widgets import display_units
        from station.outputs.units import describe_error

        return describe_error(e, display_units())   # a snapshot's limits with units
    return f"{type(e).__name__}: {e}"


class Page(QWidget):
    """A wizard page over the controller (and its session)."""

    completeChanged = Signal()
    title = ""
    subtitle = ""

    def __init__(self, controller, parent=None):
        super().__init__(parent)
        self.controller = controller
        outer = QVBoxLayout(self)
        outer.setContentsMargins(12, 8, 12, 4)
        outer.addWidget(heading(self.title))
        sub = self.subtitle_label = QLabel(self.subtitle)
        sub.setWordWrap(True)
        outer.addWidget(sub)
        self.body = QWidget()
        self.layout_ = QVBoxLayout(self.body)
        self.layout_.setContentsMargins(0, 4, 0, 0)
        outer.addWidget(scrolled(self.body), 1)

    @property
    def session(self):
        return self.controller.session

    def initialize_page(self) -> None:
        """Read the session; called whenever the page is shown."""

    def is_complete(self) -> bool:
        return True

    def leave_page(self) -> None:
        """The operator goes to another page."""

    def show_error(self, what: str, e: BaseException) -> None:
        box = QMessageBox(QMessageBox.Icon.Warning, what, f"{what}:\n{error_text(e)}",
                          QMessageBox.StandardButton.Ok, self)
        box.setObjectName("errorBox")
        box.open()
        self.last_error = box
