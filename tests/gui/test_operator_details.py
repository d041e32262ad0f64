"""Small things an operator meets (issue 23, finding 12): File > New session and Help
> Getting started, no "-0" in a number, a report the desktop cannot open is said."""
from __future__ import annotations

from PySide6.QtCore import Qt
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
    # the shared formatting too (tables, the report): issue 44's "-0"
    from station.outputs.report_context import number_text
    from station.outputs.units import MM_DEG

    assert MM_DEG.text(-0.0, "m") == "0 mm" and MM_DEG.text(-1e-9, "m", ".3f") == "0.000 mm"
    assert number_text(-0.0, ".4g") == "0" and MM_DEG.text(-2e-3, "m") == "-2 mm"


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
    assert str(report) in page.opened.text()
    # a desktop that takes the request and may start nothing: the page still says where
    monkeypatch.setattr(QDesktopServices, "openUrl", staticmethod(lambda url: True))
    assert page._open(report) is True and "if nothing opens" in page.opened.text()


def test_a_warning_stays_above_the_page_until_dismissed(qtbot, settings, answers):
    """Issue 44: "the draw-wire lost its zero" was only in the status bar, cut at its width."""
    win = MainWindow(Controller(simulate=True, settings=settings))
    qtbot.addWidget(win)
    win.show()
    long = ("back at the reference: draw-wire read 0.51234 m where its zero was 0.5 m: "
            "it lost its zero (a slipped wire or a reset counter); zeroed again")
    win.controller.eventLogged.emit({"kind": "info", "message": "captured"})
    assert not win.notice.isVisible()
    win.controller.eventLogged.emit({"kind": "warning", "message": long})
    assert win.notice.isVisible() and long in win.notice.text()
    for i in range(5):
        win.controller.eventLogged.emit({"kind": "fault", "message": f"fault {i}"})
    assert long not in win.notice.text() and "fault 4" in win.notice.text()
    qtbot.mouseClick(win.dismiss_button, Qt.MouseButton.LeftButton)
    assert not win.notice.isVisible()


def test_why_rms_before_is_n_a_is_beside_the_table(qtbot):
    from station.gui.results import CalibrationView

    view = CalibrationView()
    qtbot.addWidget(view)
    view.show_validation([{"channel": "tilt", "n": 12, "rms_before": None, "rms_after": 1e-4,
                           "unit": "rad", "note": "the nominal does not reach the held-out "
                           "poses' platform (no IK solution)"}])
    assert "RMS before n/a" in view.validation_note.text()
    assert "no IK solution" in view.validation_note.text()


def test_the_export_page_lists_the_calibrated_urdf(qtbot, settings, answers, tmp_path):
    win = MainWindow(Controller(simulate=True, settings=settings))
    qtbot.addWidget(win)
    win.show()
    page = win.page(PageId.EXPORT)
    assert page.urdf.isHidden()
    doc = {"format": "calstation-params", "version": 1, "robot": "ur5-like", "method": "sm-distance",
           "parameters": {"a": {"identifiable": True}}}
    files = {"params": str(tmp_path / "params.json"), "report": str(tmp_path / "report.html"),
             "trace": str(tmp_path / "trace.jsonl"), "checksum": "sha256:00",
             "urdf": str(tmp_path / "calibrated.urdf")}
    page._done((files, doc))
    assert not page.urdf.isHidden() and page.urdf.text().endswith("calibrated.urdf")
    page._done(({k: v for k, v in files.items() if k != "urdf"}, doc))
    assert page.urdf.isHidden()
