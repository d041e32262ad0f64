"""The wizard through a whole simulated sm-distance-tilt session: setup, jog and
capture the base origin, plan, execute with a drive fault answered Retry, close
mid-run and resume (back to the reference, draw-wire zeroed again), calibrate
(close to the simulator's truth), export (verified parameter file); then the
Offline page on a fixture trace."""
from __future__ import annotations

import json

import numpy as np
import pytest
from PySide6.QtCore import Qt

from calibration.methods.sm_distance_tilt import reframe_nominal
from calibration.robots import get_robot
from drivers.sim.truth import load_truth
from station.gui.pages import PageId
from station.outputs.params_file import read_params
from station.recording.trace import read_trace
from tests.gui.helpers import ROOT, SCREEN, cut_texts, screenshot, wait_idle, wait_measured
from tests.simconfig import quick_config

TIMEOUT = 30000


def connect(qtbot, win, folder, robot, method, count):
    setup = win.page(PageId.SETUP)
    setup.folder.setText(str(folder))
    setup.set_choice(robot, method)
    setup.count.setValue(count)
    qtbot.mouseClick(setup.connect_button, Qt.MouseButton.LeftButton)
    qtbot.waitUntil(setup.is_complete, timeout=TIMEOUT)
    return setup


@pytest.mark.heavy
def test_sm_distance_tilt_session(open_window, qtbot, tmp_path, answers):
    folder = tmp_path / "sm"
    station = str(quick_config(tmp_path / "station", "agebot-sm"))
    win = open_window(config_path=station)
    assert win.minimumSizeHint().width() <= SCREEN[0]
    assert win.minimumSizeHint().height() <= SCREEN[1]
    c = win.controller

    # 1 setup: nothing chosen yet is said in words
    setup = win.page(PageId.SETUP)
    setup.folder.setText("")
    assert any("No session folder" in t for t in setup.missing_items())
    assert not win.next_button.isEnabled()
    connect(qtbot, win, folder, "agebot-sm", "sm-distance-tilt", 24)
    assert setup.devices.rowCount() == 3 and all(setup.devices.states.values())
    assert "Connected" in setup.missing.text()
    screenshot(win, "01-setup")

    # 2 reference: a step jog, then to the suggested point, then capture
    qtbot.mouseClick(win.next_button, Qt.MouseButton.LeftButton)
    assert win.current == PageId.REFERENCE
    ref = win.page(PageId.REFERENCE)
    before = c.session.readings()["qm1"]
    ref.jog.step.setValue(2.0)
    qtbot.mouseClick(ref.jog.buttons[0][1], Qt.MouseButton.LeftButton)
    wait_idle(qtbot, c)
    assert abs(c.session.readings()["qm1"] - before - 2.0) < 0.05
    assert not win.next_button.isEnabled()
    qtbot.mouseClick(ref.goto_button, Qt.MouseButton.LeftButton)
    wait_idle(qtbot, c)
    qtbot.waitUntil(lambda: ref.picture.step == 1, timeout=5000)   # "attach the cable"
    assert "distance" in ref.readings.values
    screenshot(win, "02-reference")
    qtbot.mouseClick(ref.capture_button, Qt.MouseButton.LeftButton)
    qtbot.waitUntil(ref.is_complete, timeout=TIMEOUT)
    wait_idle(qtbot, c)
    assert c.session.reference_qm is not None

    # 3 plan: planned on entry (not edited here: a re-planned session's resume is
    # covered by the session's own tests once it replays replaced plans). The wizard
    # plans the arm in rounds (station/planning/arm_rounds.py): the scout is the plan shown
    qtbot.mouseClick(win.next_button, Qt.MouseButton.LeftButton)
    plan = win.page(PageId.PLAN)
    qtbot.waitUntil(lambda: plan.table.rowCount() == 6, timeout=TIMEOUT)
    wait_idle(qtbot, c)
    assert "6 poses to fit + 0 held out; eq. 60 minimum 35" in plan.counts.text()
    assert "scout round" in plan.counts.text()
    # 6 scout + 6 in 30 % of the box on top of the 24 asked for, in the whole box
    assert "for 36 fit poses + 4 held out in all" in plan.counts.text()
    assert plan.plot.count == 6
    screenshot(win, "03-plan")

    # 4 execute, a drive fault answered Retry, then the window closes mid-run
    qtbot.mouseClick(win.next_button, Qt.MouseButton.LeftButton)
    ex = win.page(PageId.EXECUTE)
    qtbot.mouseClick(ex.start_button, Qt.MouseButton.LeftButton)
    qtbot.waitUntil(lambda: len(c.session.measured) >= 2, timeout=TIMEOUT)
    with c.sim.control() as ctl:
        ctl.call(faults={"drive_fault_node": 2})
    qtbot.waitUntil(lambda: ex.fault_box is not None, timeout=TIMEOUT)
    box = ex.fault_box
    assert "Pose" in box.text() and "Retry" in box.informativeText()
    screenshot(box, "04-fault-dialog")
    qtbot.mouseClick(box.answer_buttons["retry"], Qt.MouseButton.LeftButton)
    qtbot.waitUntil(lambda: len(c.session.measured) >= 5, timeout=TIMEOUT)
    kinds = [e["kind"] for e in c.session.events]
    assert "fault" in kinds and "retry" in kinds
    assert not cut_texts(ex.picture)           # the rail's caption, the carriage's z
    screenshot(win, "04-execute")
    win.close()
    assert c.sim is None and c.session is None
    recorded = read_trace(folder / "trace.jsonl").poses
    assert len(recorded) >= 5

    # reopen: the last session is offered, resumed, finished
    win = open_window(config_path=station)
    c = win.controller
    answers["asked"].clear()
    assert win.offer_resume()
    assert any("Resume" in title for title, _ in answers["asked"])
    setup = win.page(PageId.SETUP)
    qtbot.waitUntil(setup.is_complete, timeout=TIMEOUT)
    s = c.session
    assert s.resumed and len(s.measured) == len(recorded) and s.pending
    assert c.needs_rezero
    for pid in (PageId.REFERENCE, PageId.PLAN, PageId.EXECUTE):
        qtbot.mouseClick(win.next_button, Qt.MouseButton.LeftButton)
        assert win.current == pid
    assert not win.page(PageId.PLAN).regenerate_button.isEnabled()   # poses recorded
    ex = win.page(PageId.EXECUTE)
    assert "Continue" in ex.start_button.text()
    # a reading disturbed at one pose still to measure (a cable brushing the wire there):
    # measured again before the page is complete, in its log (issue 40)
    disturbed = s.pending[-1]
    with c.sim.control() as ctl:
        ctl.call(faults={"glitch_qm": [float(q) for q in disturbed.qm],
                         "glitch_distance_m": 5e-4})
    qtbot.mouseClick(ex.start_button, Qt.MouseButton.LeftButton)
    # ~35 poses with their rounds' planning refits: ~6 s idle. No device fault is
    # injected here: a question to the operator (a snapshot still settling was one, with
    # a busy CI machine's inclinometer frames queued) fails at once
    wait_measured(qtbot, ex, s)
    assert c.rezeroed and not s.pending
    assert len(s.measured) == 40        # every round planned and measured (36 + 4 held out)
    again = [e for e in s.events if e["kind"] == "remeasure"]
    assert [e["plan_index"] for e in again] == [disturbed.index]
    assert s.measured[disturbed.index]["remeasure_of"] == again[0]["pose"]
    log = [ex.log.item(i).text() for i in range(ex.log.count())]
    assert any(f"[remeasure] pose {disturbed.index} measured again" in t for t in log)

    # 5 calibrate: converged, close to the simulator's truth in the captured frame
    qtbot.mouseClick(win.next_button, Qt.MouseButton.LeftButton)
    cal = win.page(PageId.CALIBRATE)
    qtbot.waitUntil(lambda: not cal.running, timeout=TIMEOUT)
    assert cal.is_complete(), cal.status.text()
    res = s.outcome.result
    # 13 robot parameters and the draw-wire's zero offset (distance_off, last)
    assert res.converged and res.n_identifiable == 14 and res.names[-1] == "distance_off"
    robot = get_robot("agebot-sm")
    truth = reframe_nominal(robot, load_truth(ROOT / "fixtures/truth/agebot-sm.json").xi(),
                            s.reference_qm)
    err = np.abs(res.x[:13] - truth)
    assert np.all(err < 6 * res.std[:13] + 1e-4 * np.maximum(1.0, np.abs(truth))), \
        dict(zip(res.names, err / res.std[:13]))
    assert cal.view.strip.columnCount() == 14
    assert cal.view.plots.history and cal.iterations >= 1
    val = {v["channel"]: v for v in s.validation}
    assert val["distance"]["rms_after"] < val["distance"]["rms_before"] / 10
    screenshot(win, "05-calibrate")

    # 6 export: the parameter file verifies, its checksum is shown
    qtbot.mouseClick(win.next_button, Qt.MouseButton.LeftButton)
    exp = win.page(PageId.EXPORT)
    qtbot.waitUntil(exp.is_complete, timeout=TIMEOUT)
    doc = read_params(folder / "params.json")
    assert exp.checksum.text() == doc["checksum"]
    assert doc["method"] == "sm-distance-tilt" and (folder / "report.html").exists()
    assert "checksum OK" in exp.verified.text()
    screenshot(win, "06-export")
    assert json.loads((folder / "params.json").read_text())["checksum"] == doc["checksum"]

    # 7 offline: a recorded trace, calibrated in the GUI, saved
    assert win.go_to(PageId.OFFLINE)
    off = win.page(PageId.OFFLINE)
    assert off.open_trace(ROOT / "fixtures/traces/sm-distance-tilt.jsonl")
    qtbot.mouseClick(off.calibrate_button, Qt.MouseButton.LeftButton)
    qtbot.waitUntil(lambda: off.outcome is not None, timeout=TIMEOUT)
    assert off.view.plots.history
    out = tmp_path / "offline-params.json"
    assert off.save_params(out) is not None
    assert read_params(out)["method"] == "sm-distance-tilt"
    off.save_report(tmp_path / "offline-report.html")
    qtbot.waitUntil(lambda: "report" in off.saved, timeout=TIMEOUT)
    assert (tmp_path / "offline-report.html").stat().st_size > 1000
    screenshot(win, "07-offline")
