"""The wizard through a whole simulated pm-fk session of the wrist: mounting
check, the scout plan edited and regenerated, execute (scout round, then the
main round planned from it) with a drive fault answered Skip, calibrate
(q3_off and k3 not identifiable, with influence), export."""
from __future__ import annotations

import time

import pytest

from PySide6.QtCore import Qt

from station.gui.pages import PageId
from station.outputs.params_file import read_params
from station.planning.wrist_plan import PM_SCOUT_COUNT
from tests.gui.helpers import cut_texts, screenshot, wait_idle, wait_measured
from tests.gui.test_wizard_sm import TIMEOUT, connect
from tests.simconfig import quick_config


@pytest.mark.heavy
def test_pm_fk_session(open_window, qtbot, tmp_path):
    folder = tmp_path / "pm"
    win = open_window(config_path=str(quick_config(tmp_path / "station", "agebot-pm", speed=1.0)))
    c = win.controller
    connect(qtbot, win, folder, "agebot-pm", "pm-fk", 14)
    screenshot(win, "wrist-01-setup")

    # 2 reference: the wrist needs none; the inclinometer mounting check
    qtbot.mouseClick(win.next_button, Qt.MouseButton.LeftButton)
    ref = win.page(PageId.REFERENCE)
    assert ref.capture_button is None and ref.confirm is not None
    qtbot.waitUntil(lambda: ref.picture.level is not None, timeout=5000)
    assert ref.picture.level                   # the simulated sensor is mounted flat
    assert not win.next_button.isEnabled()
    # continuous jog while the button is held, under the speed limit (1 % of 3000 u/s)
    ref.jog.continuous_mode.setChecked(True)
    ref.jog.speed.setValue(1)
    q0 = c.session.readings()["qm1"]
    plus = ref.jog.buttons[0][1]
    t0 = time.monotonic()
    qtbot.mousePress(plus, Qt.MouseButton.LeftButton)
    qtbot.wait(600)
    qtbot.mouseRelease(plus, Qt.MouseButton.LeftButton)
    elapsed = time.monotonic() - t0
    wait_idle(qtbot, c)
    moved = c.session.readings()["qm1"] - q0
    assert 3.0 < moved <= 30.0 * elapsed + 3.5
    ref.confirm.setChecked(True)
    assert win.next_button.isEnabled()
    screenshot(win, "02-reference-wrist")

    # 3 plan: the scout round; edit one pose, then regenerate with another seed
    qtbot.mouseClick(win.next_button, Qt.MouseButton.LeftButton)
    plan = win.page(PageId.PLAN)
    qtbot.waitUntil(lambda: plan.table.rowCount() == PM_SCOUT_COUNT, timeout=TIMEOUT)
    wait_idle(qtbot, c)
    assert "scout round" in plan.counts.text()
    first = c.session.plan_poses[0]
    plan.table.selectRow(0)
    qtbot.mouseClick(plan.toggle_button, Qt.MouseButton.LeftButton)
    wait_idle(qtbot, c)
    assert c.session.plan_poses[0].use == "validation" and first.use == "fit"
    assert plan.table.item(0, 1).text() == "held out"
    plan.table.selectRow(1)
    qtbot.mouseClick(plan.remove_button, Qt.MouseButton.LeftButton)
    wait_idle(qtbot, c)
    assert len(c.session.plan_poses) == PM_SCOUT_COUNT - 1
    plan.seed.setValue(5)
    qtbot.mouseClick(plan.regenerate_button, Qt.MouseButton.LeftButton)
    wait_idle(qtbot, c)
    assert len(c.session.plan_poses) == PM_SCOUT_COUNT
    assert all(p.use == "fit" for p in c.session.plan_poses)
    assert c.session.plan_poses[0].qm != first.qm
    screenshot(win, "wrist-03-plan")

    # 4 execute: a drive fault answered Skip; the main round follows the scout round
    qtbot.mouseClick(win.next_button, Qt.MouseButton.LeftButton)
    ex = win.page(PageId.EXECUTE)
    qtbot.mouseClick(ex.start_button, Qt.MouseButton.LeftButton)
    qtbot.waitUntil(lambda: len(c.session.measured) >= 3, timeout=TIMEOUT)
    qtbot.mouseClick(ex.pause_button, Qt.MouseButton.LeftButton)
    assert c.session.paused and ex.resume_button.isEnabled()
    qtbot.mouseClick(ex.resume_button, Qt.MouseButton.LeftButton)
    assert not c.session.paused
    with c.sim.control() as ctl:
        ctl.call(faults={"drive_fault_node": 1})
    qtbot.waitUntil(lambda: ex.fault_box is not None, timeout=TIMEOUT)
    qtbot.mouseClick(ex.fault_box.answer_buttons["skip"], Qt.MouseButton.LeftButton)
    # (the rounds take 15 s alone): a second question to the operator fails at once
    s = c.session
    wait_measured(qtbot, ex, s)
    assert len(s.skipped) == 1 and ex.faults_asked == 1
    assert any(p.round == 1 for p in s.plan_poses)          # the main round was planned
    assert len(s.measured) == len(s.plan_poses) - 1
    assert "skip" in [e["kind"] for e in s.events]
    assert not cut_texts(ex.picture)           # the bubble level's caption and reading
    screenshot(win, "wrist-04-execute")

    # 5 calibrate: the wrist's q3_off and k3 are not identifiable, with influence
    qtbot.mouseClick(win.next_button, Qt.MouseButton.LeftButton)
    cal = win.page(PageId.CALIBRATE)
    qtbot.waitUntil(lambda: not cal.running, timeout=TIMEOUT)
    assert cal.is_complete(), cal.status.text()
    res = s.outcome.result
    status = dict(zip(res.names, res.status))
    assert not status["q3_off"].identifiable and status["q3_off"].influences_model
    assert not status["k3"].identifiable and status["k3"].influences_model
    symbols = cal.view.strip.symbols()        # parameter name -> the symbol under it
    assert symbols["k3"] == "\u25cf" and symbols["a1"] == "\u2713"
    assert list(symbols) == list(res.names)
    assert s.validation and all(v["rms_after"] < 1e-3 for v in s.validation)
    screenshot(win, "05-calibrate-wrist")

    # 6 export
    qtbot.mouseClick(win.next_button, Qt.MouseButton.LeftButton)
    exp = win.page(PageId.EXPORT)
    qtbot.waitUntil(exp.is_complete, timeout=TIMEOUT)
    doc = read_params(folder / "params.json")
    assert doc["method"] == "pm-fk" and exp.checksum.text() == doc["checksum"]
    screenshot(win, "wrist-06-export")
