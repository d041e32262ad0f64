"""The question a device fault asks the operator while the robot measures: Retry, Skip
or Abort, as a window-modal dialog (the worker waits for the answer; the window keeps
drawing). The Execute page asks it of a session's pose, the Accuracy step of a test's
cycle; the words differ, the dialog is this one."""
from __future__ import annotations

from PySide6.QtWidgets import QMessageBox


def ask(page, request, answer, *, name: str, text: str, informative: str,
        skip_label: str, suggested: str = "retry") -> QMessageBox:
    """Open the dialog over ``page`` for the worker's ``request``; the operator's choice
    (``"retry"``, ``"skip"``, ``"abort"``; closing the dialog aborts) goes to
    ``answer(request, choice)`` and ``page.fault_box`` is the open dialog until then.
    ``suggested``: the default button (``"skip"`` where the pose, not the device, is at
    fault)."""
    box = QMessageBox(page)
    box.setObjectName(name)
    box.setIcon(QMessageBox.Icon.Warning)
    box.setWindowTitle("Device fault")
    box.setText(text)
    box.setInformativeText(informative)
    retry = box.addButton("&Retry", QMessageBox.ButtonRole.AcceptRole)
    skip = box.addButton(skip_label, QMessageBox.ButtonRole.ActionRole)
    abort = box.addButton("&Abort", QMessageBox.ButtonRole.RejectRole)
    box.setDefaultButton(skip if suggested == "skip" else retry)
    box.suggested = suggested
    box.setEscapeButton(abort)
    answers = {retry: "retry", skip: "skip", abort: "abort"}
    box.answer_buttons = {v: k for k, v in answers.items()}

    def clicked(button):
        answer(request, answers.get(button, "abort"))
        page.fault_box = None

    box.buttonClicked.connect(clicked)
    box.rejected.connect(lambda: request.event.is_set() or answer(request, "abort"))
    page.fault_box = box
    box.open()
    return box
