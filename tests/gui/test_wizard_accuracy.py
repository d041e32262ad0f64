"""The wizard's Accuracy step (docs/accuracy.md, "In the wizard"): ISO 9283's AP and RP
before and after the calibration, after the Export step.

Fast: a session measured by the station's own sensors (a draw-wire, an inclinometer) is
told in one line why the test does not apply, and the step is done (skipped); the
results of a made-up test (:func:`tests.station.iso_helpers.made_up_test`) in the
step's tables are the printed ones and fit 1366x768; a device fault asks Retry / Skip
the cycle / Abort. Slow (a simulated URDF session and two runs of the test, some 40 s on
2 cores; CI runs it): the operator stops a test (nothing written), then a test of 2
cycles with a drive fault retried: the table, the CSV and the page in the session
folder, the page linked from its report."""
from __future__ import annotations

import html
from types import SimpleNamespace

import numpy as np
import pytest
from PySide6.QtCore import Qt
from PySide6.QtWidgets import QScrollArea

from drivers.errors import DeviceError
from station.gui.pages import PageId
from station.gui.worker import FaultQuestion
from station.outputs.iso9283 import table
from station.session.iso_run import Where
from tests.gui.helpers import FRAMED, SCREEN, screenshot, wait_idle
from tests.station.iso_helpers import calibrate, made_up_test

TIMEOUT = 60000
URDF_ROBOT = SimpleNamespace(name="m10ia_like", calibrated_origins=None)


def _stand_in(out, method="sm-markers", robot=URDF_ROBOT):
    """A session as the step reads it (the steps before it, that it is not theirs to
    complete; the window closes it)."""
    return SimpleNamespace(method=method, robot=robot, out=out, abort=lambda: None,
                           close=lambda: None, needs_reference=False, plan_poses=[],
                           outcome=None)


def _show(qtbot, win, session):
    """The Accuracy step over ``session``, whether or not the steps before it are done."""
    win.controller.session = session
    page = win.page(PageId.ACCURACY)
    win.current = PageId.ACCURACY          # as go_to shows a page, without its lock
    win.stack.setCurrentWidget(page)
    win.steps.blockSignals(True)
    win.steps.setCurrentRow(int(PageId.ACCURACY))
    win.steps.blockSignals(False)
    page.initialize_page()
    qtbot.wait(50)
    return page


def test_the_station_s_own_sensors_do_not_give_the_test_a_position(open_window, qtbot,
                                                                    tmp_path):
    win = open_window()
    for method, robot in (("sm-distance-tilt", URDF_ROBOT),
                          ("sm-distance", SimpleNamespace(name="agebot-sm"))):
        page = _show(qtbot, win, _stand_in(tmp_path, method, robot))
        text = page.why.text()
        assert page.why.isVisible() and "\n" not in text, text
        assert f"session's {method}" in text and "draw-wire's one distance" in text
        assert text.startswith("The test does not apply here") and not page.test.isVisible()
        assert text.endswith("Skip this step.")
        assert not page.start_button.isEnabled() and not page.cycles.isEnabled()
        assert page.is_complete()              # skipped: nothing to do here
        screenshot(win, "accuracy-00-does-not-apply")
    # a motion capture's session before its parameter file is written: said, not started
    page = _show(qtbot, win, _stand_in(tmp_path))
    assert "write it on the Export step" in page.why.text() and not page.is_complete()
    assert page.cycles.value() == 30 and page.cycles.minimum() == 2
    page.cycles.setValue(5)
    assert "fewer than the standard's 30" in page.cycles_note.text()
    win.controller.session = None


def test_the_results_are_the_printed_table_and_fit_the_screen(open_window, qtbot, tmp_path):
    from station.outputs.iso9283 import csv_text
    from station.outputs.iso9283_csv import read

    folder = calibrate(tmp_path / "s", params="params.json")
    plan, readings = made_up_test(folder, 3, params="params.json")
    text = csv_text(plan.tm, plan.cube, readings, plan.names)
    f = read(folder / "accuracy.csv", folder / "params.json", text=text)
    win = open_window()
    page = _show(qtbot, win, _stand_in(folder))
    assert page.why.text() == "" and page.start_button.isEnabled()
    page._lines = [f"the page: linked from {folder / 'report.html'}"]
    page._done(f)
    printed = {ln.split()[0]: ln.split()[1:] for ln in table(f.res)[1:6]}
    for r in range(5):
        cells = [page.table.item(r, c).text() for c in range(page.table.columnCount())]
        name, apb, apa, _factor, rpb, rpa, _pred = cells
        assert [apb, apa, rpb, rpa] == printed[name], (cells, printed[name])
    assert page.table.item(5, 0).text() == "mean"
    assert page.orientation.isVisible() and page.orientation.rowCount() == 5
    assert "times closer" in page.summary.text() and "times closer" in page.status.text()
    assert "accuracy.csv" in page.written.text() and "linked from" in page.written.text()
    assert page.is_complete() and page.open_button.isEnabled()
    for size in (SCREEN, FRAMED):
        win.resize(*size)
        qtbot.wait(100)
        area = page.findChild(QScrollArea)
        assert area.horizontalScrollBar().maximum() == 0, size
    win.resize(*SCREEN)
    win.controller.session = None


def test_a_device_fault_asks_retry_skip_the_cycle_or_abort(open_window, qtbot):
    win = open_window()
    page = win.page(PageId.ACCURACY)
    where = Where("compensated", 3, 30, "P4")
    for answer in ("retry", "skip", "abort"):
        req = FaultQuestion.Request(where, DeviceError("no answer", device="canopen node 2"),
                                    0)
        page.ask_fault(req)
        box = page.fault_box
        assert "P4 of cycle 3 of 30, the compensated program" in box.text()
        assert "canopen node 2" in box.informativeText()
        assert box.defaultButton() is box.answer_buttons["retry"]
        qtbot.mouseClick(box.answer_buttons[answer], Qt.MouseButton.LeftButton)
        assert req.event.is_set() and req.reply == answer and page.fault_box is None


@pytest.mark.slow       # a simulated session and the test twice (some 40 s): CI runs it
def test_the_accuracy_step_measures_the_session_s_robot(open_window, qtbot, tmp_path):
    from drivers.robot_file import urdf_ref
    from tests.station.urdf_helpers import URDF

    pre = calibrate(tmp_path / "pre", params="params.json", speed=12.0, frames=3)
    win = open_window(config_path=str(pre / "station.toml"))
    c = win.controller
    folder = tmp_path / "session"
    setup = win.page(PageId.SETUP)
    setup.folder.setText(str(folder))
    setup.set_choice(urdf_ref(URDF, "base_link", "tool0"), "sm-markers")
    setup.truth.setText(str(pre / "truth.json"))
    qtbot.mouseClick(setup.connect_button, Qt.MouseButton.LeftButton)
    qtbot.waitUntil(setup.is_complete, timeout=TIMEOUT)
    wait_idle(qtbot, c)
    s = c.session
    # the session's export, as the Export step writes it: the parameter file, a report
    (folder / "params.json").write_bytes((pre / "params.json").read_bytes())
    from station.outputs.params_file import read_params

    checksum = read_params(folder / "params.json")["checksum"]
    (folder / "report.html").write_text(f"<html><main><p>{checksum}</p><footer>report"
                                        "</footer></main></html>\n")
    page = _show(qtbot, win, s)
    assert page.applies() is None and page.start_button.isEnabled()

    # stopped: nothing written
    qtbot.mouseClick(page.start_button, Qt.MouseButton.LeftButton)
    assert page.running and page.stop_button.isEnabled()
    qtbot.waitUntil(lambda: page.progress.value() >= 2, timeout=TIMEOUT)
    assert "cycle 1 of 30" in page.current.text(), page.current.text()
    screenshot(win, "accuracy-01-running")
    qtbot.mouseClick(page.stop_button, Qt.MouseButton.LeftButton)
    qtbot.waitUntil(lambda: not page.running, timeout=TIMEOUT)
    assert page.status.text().startswith("The test stopped before"), page.status.text()
    assert "nothing written" in page.status.text()
    assert not (folder / "accuracy.csv").exists() and not (folder / "accuracy.html").exists()
    assert not page.is_complete() and not page.results_box.isVisible()

    # 2 cycles, a drive's fault on the way retried
    page.cycles.setValue(2)
    qtbot.mouseClick(page.start_button, Qt.MouseButton.LeftButton)
    qtbot.waitUntil(lambda: page.progress.value() >= 1, timeout=TIMEOUT)
    with c.sim.control() as ctl:
        ctl.call(faults={"drive_fault_node": 2})
    qtbot.waitUntil(lambda: page.fault_box is not None or not page.running, timeout=TIMEOUT)
    assert page.fault_box is not None, page.status.text()
    qtbot.mouseClick(page.fault_box.answer_buttons["retry"], Qt.MouseButton.LeftButton)
    qtbot.waitUntil(lambda: not page.running, timeout=TIMEOUT)
    assert page.figures is not None, page.status.text()
    f = page.figures
    assert f.cycles == 2 and f.factor > 20, f.factor
    # the instrument's noise drawn fresh per reading while the test runs (a session's is a
    # function of the pose): RP holds it, as at a real station
    rps = [p.rp for prog in f.res for p in f.res[prog]]
    print("RP_l per pose and program (mm):", [round(v * 1e3, 4) for v in rps])
    assert min(rps) > 0 and float(np.mean(rps)) > 0.015e-3, rps     # m
    assert page.progress.value() == page.progress.maximum() == 20
    printed = {ln.split()[0]: ln.split()[1:] for ln in table(f.res)[1:6]}
    for r in range(5):
        cells = [page.table.item(r, k).text() for k in range(page.table.columnCount())]
        assert [cells[1], cells[2], cells[4], cells[5]] == printed[cells[0]]
    assert (folder / "accuracy.csv").is_file()
    text = html.unescape((folder / "accuracy.html").read_text())
    assert "\n".join(table(f.res)) in text
    assert 'href="accuracy.html"' in (folder / "report.html").read_text()
    assert "linked from" in page.written.text()
    assert page.is_complete()
    screenshot(win, "accuracy-02-results")
