"""Closing the window while poses are measured (issue 44): the robot stops after the
current pose while the question is open; No goes on measuring, Yes closes."""
from __future__ import annotations

import time

from PySide6.QtCore import Qt
from PySide6.QtWidgets import QMessageBox

from tests.gui.helpers import to_execute
from tests.simconfig import quick_config

TIMEOUT = 60000


def _measuring(open_window, qtbot, tmp_path, count=12):
    win = open_window(config_path=str(quick_config(tmp_path / "station", "agebot-sm")))
    c = win.controller
    ex = to_execute(win, qtbot, tmp_path / "s", count, TIMEOUT)
    qtbot.mouseClick(ex.start_button, Qt.MouseButton.LeftButton)
    qtbot.waitUntil(lambda: len(c.session.measured) >= 2, timeout=TIMEOUT)
    return win, c, ex


def test_closing_mid_run_pauses_while_asking(open_window, qtbot, tmp_path, monkeypatch):
    win, c, ex = _measuring(open_window, qtbot, tmp_path)
    seen = {}

    def question(parent, title, text, *args, **kwargs):
        s = c.session
        seen["paused"] = s.paused
        # the question stays open a while: at most the pose under way is recorded
        start = len(s.measured)
        time.sleep(2.0)
        seen["during"] = len(s.measured) - start
        seen["text"] = text
        return seen.get("answer", QMessageBox.StandardButton.No)

    monkeypatch.setattr(QMessageBox, "question", staticmethod(question))
    assert not win.close()                       # No: the window stays, measuring goes on
    assert seen["paused"] and seen["during"] <= 1, seen
    assert "paused" in seen["text"]
    assert ex.running and not c.session.paused
    n = len(c.session.measured)
    qtbot.waitUntil(lambda: len(c.session.measured) > n or not ex.running, timeout=TIMEOUT)
    seen["answer"] = QMessageBox.StandardButton.Yes
    assert win.close()
