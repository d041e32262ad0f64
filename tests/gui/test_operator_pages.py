"""Pages as an operator meets them: a reference captured far from the mark is
warned about and can be captured again (the trace keeps the new one), and a session
set up without rounds plans every pose at once; the Offline
page after a failed open shows one line and nothing of the previous trace; the
window fits the screen it opens on; the wheel over a plot scrolls the page."""
from __future__ import annotations

from PySide6.QtCore import QPoint, QPointF, Qt
from PySide6.QtGui import QWheelEvent
from PySide6.QtWidgets import QApplication, QScrollArea

from station.gui.controller import Controller
from station.gui.pages import PageId
from station.gui.pictures import FAR_M
from station.gui.window import MainWindow
from station.recording.trace import read_trace
from tests.gui.helpers import ROOT, wait_idle
from tests.gui.test_wizard_sm import TIMEOUT, connect
from tests.simconfig import quick_config


def test_far_reference_is_warned_and_captured_again(open_window, qtbot, tmp_path):
    folder = tmp_path / "sm"
    win = open_window(config_path=str(quick_config(tmp_path / "station", "agebot-sm")))
    c = win.controller
    setup = win.page(PageId.SETUP)
    setup.set_choice("agebot-pm", "pm-fk")
    assert not setup.rounds.isEnabled()              # the wrist always grows its box
    setup.set_choice("agebot-sm", "sm-distance-tilt")
    assert setup.rounds.isEnabled() and setup.rounds.isChecked()   # the default: rounds
    setup.rounds.setChecked(False)                   # app.py run --one-shot
    connect(qtbot, win, folder, "agebot-sm", "sm-distance-tilt", 24)
    assert not c.session.request.grow
    qtbot.mouseClick(win.next_button, Qt.MouseButton.LeftButton)
    assert win.current == PageId.REFERENCE
    ref = win.page(PageId.REFERENCE)
    assert not ref.capture_button.isHidden() and ref.recapture_button.isHidden()
    # captured where the arm stands (home), far from the suggested mark
    qtbot.mouseClick(ref.capture_button, Qt.MouseButton.LeftButton)
    qtbot.waitUntil(ref.is_complete, timeout=TIMEOUT)
    wait_idle(qtbot, c)
    first = c.session.reference_qm.copy()
    off = c.session.reference_offset()
    assert off > FAR_M
    text = ref.status.text()
    assert "from the suggested mark" in text and c.units.text(off, "m", ".4g") in text
    assert 0 in ref.picture.warned and 0 not in ref.picture.done   # step 1 not ticked
    assert not ref.recapture_button.isHidden() and ref.recapture_button.isEnabled()
    # to the mark, capture again: the new reference replaces the old one
    qtbot.mouseClick(ref.goto_button, Qt.MouseButton.LeftButton)
    wait_idle(qtbot, c)
    qtbot.mouseClick(ref.recapture_button, Qt.MouseButton.LeftButton)
    qtbot.waitUntil(lambda: abs(c.session.reference_qm - first).max() > 1e-3, timeout=TIMEOUT)
    wait_idle(qtbot, c)
    assert c.session.reference_offset() < FAR_M
    assert ref.status.text().startswith("\u2713 Reference captured")
    assert 0 in ref.picture.done and not ref.picture.warned
    trace = read_trace(folder / "trace.jsonl")       # what a resumed session reads
    assert trace.reference["qm"] == list(c.session.reference_qm)
    assert any("captured again" in e["message"] for e in trace.events)
    refs = [line for line in (folder / "trace.jsonl").read_text().splitlines()
            if '"record":"reference"' in line.replace(" ", "")]
    assert len(refs) == 2
    # without rounds the plan is every pose at once, no scout
    qtbot.mouseClick(win.next_button, Qt.MouseButton.LeftButton)
    plan = win.page(PageId.PLAN)
    qtbot.waitUntil(lambda: plan.table.rowCount() > 24, timeout=TIMEOUT)
    wait_idle(qtbot, c)
    assert c.session.rounds is None and "scout" not in plan.counts.text()
    assert plan.counts.text().startswith("24 poses to fit + ")


def test_offline_failed_open_clears_the_page(qtbot, settings, answers, tmp_path):
    win = MainWindow(Controller(simulate=False, settings=settings))
    qtbot.addWidget(win)
    win.show()
    qtbot.waitExposed(win)
    try:
        off = win.page(PageId.OFFLINE)
        assert off.open_trace(ROOT / "fixtures/traces/sm-distance.jsonl")
        off.calibrate()
        qtbot.waitUntil(lambda: off.outcome is not None, timeout=TIMEOUT)
        assert off.save_button.isEnabled() and off.view.params.rowCount() > 0
        assert off.status.text().startswith("\u2713")           # the "converged" line
        bad = tmp_path / "notes.jsonl"
        bad.write_text("these are my notes\n")
        assert not off.open_trace(bad)
        line = off.summary.text()
        assert line.startswith("notes.jsonl cannot be opened: line 1: not valid JSON")
        assert "\n" not in line and "JSONDecodeError" not in line and len(line) < 200
        assert off.status.text() == "" and off.outcome is None and off.path is None
        assert off.view.params.rowCount() == 0 and off.view.validation.rowCount() == 0
        assert off.view.summary.text() == "Not calibrated yet."
        assert off.view.plots.history == []
        for b in (off.calibrate_button, off.save_button, off.report_button):
            assert not b.isEnabled()
    finally:
        win.controller.shutdown()


def test_window_fits_its_screen_and_the_wheel_scrolls_the_page(qtbot, settings, answers):
    win = MainWindow(Controller(simulate=False, settings=settings))
    qtbot.addWidget(win)
    win.show_fitted()
    qtbot.waitExposed(win)
    try:
        qtbot.wait(300)                          # the refit once framed
        avail = win.screen().availableGeometry()    # offscreen: 800 x 800, no frame
        hint = win.minimumSizeHint()
        assert win.frameGeometry().width() <= max(avail.width(), hint.width())
        assert win.frameGeometry().height() <= max(avail.height(), hint.height())
        assert win.width() < 1440 and win.height() < 900   # not the preferred size
        win.resize(900, 500)                     # small: the Offline page must scroll
        win.go_to(PageId.OFFLINE)
        off = win.page(PageId.OFFLINE)
        QApplication.processEvents()
        area = off.findChild(QScrollArea)
        bar = area.verticalScrollBar()
        assert bar.maximum() > 0
        canvas = off.view.plots
        pos = QPointF(canvas.width() / 2, canvas.height() / 2)
        ev = QWheelEvent(pos, canvas.mapToGlobal(pos), QPoint(0, 0), QPoint(0, -120),
                         Qt.MouseButton.NoButton, Qt.KeyboardModifier.NoModifier,
                         Qt.ScrollPhase.NoScrollPhase, False)
        before = bar.value()
        QApplication.sendEvent(canvas, ev)
        QApplication.processEvents()
        assert bar.value() > before
    finally:
        win.controller.shutdown()


def test_results_name_pm_tilts_heading_as_not_identified(qtbot):
    """The results view of a pm-tilt calibration says the heading is not identified,
    with its std; pm-fk's does not."""
    from station.fitting.batch import calibrate_trace
    from station.gui.results import CalibrationView

    view = CalibrationView()
    qtbot.addWidget(view)
    view.show_outcome(calibrate_trace(str(ROOT / "fixtures" / "traces" / "pm-tilt.jsonl")))
    assert "not identified: heading" in view.notes.text() and "actuator units" in view.notes.text()
    view.show_outcome(calibrate_trace(str(ROOT / "fixtures" / "traces" / "pm-fk.jsonl")))
    assert "heading" not in view.notes.text()
