"""pytest-qt fixtures for the wizard (offscreen: tests/conftest.py sets QT_QPA_PLATFORM).

``CALSTATION_SCREENSHOTS=1`` saves a screenshot of every page, taken from the
real widgets at 1366x768, into docs/screenshots/; ``CALSTATION_SCREENSHOTS=root``
takes the whole X screen (run under Xvfb at 1366x768 with a window manager and
``QT_QPA_PLATFORM=xcb``; see tests/gui/helpers.py).
"""
from __future__ import annotations

import pytest
from PySide6.QtCore import QSettings
from PySide6.QtWidgets import QMessageBox

from tests.gui.helpers import SCREEN


@pytest.fixture
def settings(tmp_path):
    return QSettings(str(tmp_path / "gui.ini"), QSettings.Format.IniFormat)


@pytest.fixture
def answers(monkeypatch):
    """What QMessageBox.question answers (Yes unless a test changes it); every question
    asked is recorded."""
    state = {"answer": QMessageBox.StandardButton.Yes, "asked": []}

    def question(parent, title, text, *args, **kwargs):
        state["asked"].append((title, text))
        return state["answer"]

    monkeypatch.setattr(QMessageBox, "question", staticmethod(question))
    return state


@pytest.fixture
def open_window(qtbot, settings, answers):
    """A factory of wizard windows over simulated devices; each is shut down at the end
    (simulator stopped) whatever the test did."""
    from station.gui.controller import Controller
    from station.gui.window import MainWindow

    made = []

    def make(**kwargs):
        controller = Controller(simulate=True, settings=settings,
                                **{"sim_seed": 7, **kwargs})
        win = MainWindow(controller)
        qtbot.addWidget(win)
        win.resize(*SCREEN)
        win.show()
        qtbot.waitExposed(win)
        made.append(win)
        return win

    yield make
    for win in made:
        win.controller.shutdown()
        win.close()
