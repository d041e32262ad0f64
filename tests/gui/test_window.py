"""The wizard without devices: what is missing is said in words, steps open in
order, keyboard mnemonics, the window fits 1366x768, and the entry point."""
from __future__ import annotations

import argparse

import pytest
from PySide6.QtCore import Qt

from station.gui.controller import Controller, summarize_folder
from station.gui.pages import PageId
from station.gui.window import MainWindow
from tests.gui.helpers import ROOT, SCREEN


@pytest.fixture
def window(qtbot, settings, answers):
    win = MainWindow(Controller(simulate=False, settings=settings))
    qtbot.addWidget(win)
    win.resize(*SCREEN)
    win.show()
    qtbot.waitExposed(win)
    yield win
    win.controller.shutdown()


def test_missing_config_is_said_and_steps_open_in_order(window, qtbot):
    setup = window.page(PageId.SETUP)
    assert any("No station config" in t for t in setup.missing_items())
    assert "No station config" in setup.missing.text()
    qtbot.mouseClick(setup.connect_button, Qt.MouseButton.LeftButton)
    assert window.controller.session is None and not window.controller.jobs.busy
    assert not window.next_button.isEnabled()
    for pid in (PageId.REFERENCE, PageId.PLAN, PageId.EXECUTE, PageId.CALIBRATE,
                PageId.EXPORT):
        assert not window.reachable(pid)
        assert not window.steps.item(int(pid)).flags() & Qt.ItemFlag.ItemIsEnabled
    assert window.reachable(PageId.OFFLINE)
    window.steps.setCurrentRow(int(PageId.PLAN))         # a click on a locked step
    assert window.current == PageId.SETUP
    window.steps.setCurrentRow(int(PageId.OFFLINE))
    assert window.current == PageId.OFFLINE


def test_keyboard_back_and_fits_the_screen(window, qtbot):
    hint = window.minimumSizeHint()
    assert hint.width() <= SCREEN[0] and hint.height() <= SCREEN[1]
    for pid in PageId:
        page = window.page(pid)
        assert page.minimumSizeHint().width() <= SCREEN[0] - window.steps.width()
    assert window.go_to(PageId.OFFLINE)
    window.activateWindow()
    qtbot.keyClick(window, Qt.Key.Key_B, Qt.KeyboardModifier.AltModifier)   # "< &Back"
    qtbot.waitUntil(lambda: window.current == PageId.SETUP, timeout=2000)


def test_offline_page_reports_an_unreadable_trace(window, tmp_path):
    bad = tmp_path / "bad.jsonl"
    bad.write_text("not json\n")
    off = window.page(PageId.OFFLINE)
    assert not off.open_trace(bad)
    assert "cannot be opened" in off.summary.text()
    assert not off.calibrate_button.isEnabled()
    assert off.open_trace(ROOT / "fixtures/traces/pm-fk.jsonl")
    assert "pm-fk" in off.summary.text() and off.calibrate_button.isEnabled()


def test_summarize_folder(tmp_path):
    assert summarize_folder(tmp_path) is None
    (tmp_path / "trace.jsonl").write_bytes((ROOT / "fixtures/traces/sm-distance.jsonl")
                                           .read_bytes())
    s = summarize_folder(tmp_path)
    assert s.robot == "agebot-sm" and s.method == "sm-distance" and s.measured == 0
    assert s.unfinished and "sm-distance session" in s.sentence()


def test_entry_point_refuses_a_missing_config(tmp_path):
    from calibration.errors import ConfigError
    from station.gui.app import main

    with pytest.raises(ConfigError, match="no such station config"):
        main(argparse.Namespace(simulate=False, config=str(tmp_path / "none.toml")))


def test_entry_point_without_a_display_says_so(tmp_path):
    """Qt aborts (core dump) without a display; the entry point says it in one line."""
    import os
    import subprocess
    import sys
    from pathlib import Path

    env = {k: v for k, v in os.environ.items()
           if k not in ("QT_QPA_PLATFORM", "DISPLAY", "WAYLAND_DISPLAY")}
    app = Path(__file__).resolve().parents[2] / "app.py"
    r = subprocess.run([sys.executable, str(app)], env=env, capture_output=True, text=True,
                       timeout=60)
    assert r.returncode == 2
    assert r.stderr.strip().startswith("error: no display for the wizard")
