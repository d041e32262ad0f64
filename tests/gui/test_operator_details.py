"""Small things an operator meets (issue 23, finding 12): File > New session and Help
> Getting started, no "-0" in a number, a report the desktop cannot open is said."""
from __future__ import annotations

from PySide6.QtGui import QDesktopServices

from station.gui.controller import Controller
from station.gui.pages import PageId
from station.gui.window import MainWindow


def test_menus_have_new_session_and_getting_started(qtbot, settings, answers):
    win = MainWindow(Controller(simulate=True, settings=settings))
    qtbot.addWidget(win)
    menus = {m.title().replace("&", ""): [a.text().replace("&", "") for a in m.actions()]
             for m in (a.menu() for a in win.menuBar().actions())}
    assert "New session" in menus["File"]
    assert "Getting started" in menus["Help"] and len(menus["Help"]) >= 2
    setup = win.page(PageId.SETUP)
    old = setup.folder.text()
    setup.folder.setText("/tmp/somewhere-else")
    assert win.go_to(PageId.OFFLINE)
    win.new_session()
    assert win.current == PageId.SETUP and setup.folder.text() not in ("", "/tmp/somewhere-else")
    assert old


def test_no_minus_zero():
    from station.gui.widgets import channel_text, fixed

    assert fixed(-0.0004, 3) == "0.000" and fixed(-0.0006, 3) == "-0.001"
    assert channel_text("distance", -1e-8)[0] == "0.000"


def test_a_report_that_cannot_be_opened_is_said(qtbot, settings, answers, monkeypatch,
                                                tmp_path):
    win = MainWindow(Controller(simulate=True, settings=settings))
    qtbot.addWidget(win)
    monkeypatch.setattr(QDesktopServices, "openUrl", staticmethod(lambda url: False))
    page = win.page(PageId.EXPORT)
    report = tmp_path / "report.html"
    assert page._open(report) is False
    box = page.last_error
    assert box.objectName() == "notOpened" and str(report) in box.text()
