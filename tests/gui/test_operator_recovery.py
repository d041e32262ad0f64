"""The wizard as an operator drives it (issue 23): the setup page shows what the
session does (the README's default method; robot, method and folder locked while a
session is open), and a simulator that dies mid-session is survived: Retry and
Continue connect anew and go on, Connect reconnects the same session, messages
carry no raw settings and no cable advice for a simulated station, and the steps
done keep their check marks."""
from __future__ import annotations

import os
import signal

from PySide6.QtCore import Qt

from station.gui.pages import PageId
from tests.gui.helpers import to_execute, wait_idle
from tests.simconfig import quick_config

TIMEOUT = 60000


def _kill_simulator(c) -> None:
    """The simulated devices' process (and its children) gone, as after a crash."""
    os.killpg(c.sim.proc.pid, signal.SIGKILL)
    c.sim.proc.wait(10)


def _marked(win, pid) -> bool:
    return win.steps.item(int(pid)).text().startswith("\u2713")


def test_default_method_is_the_readmes(open_window, qtbot, tmp_path):
    win = open_window(config_path=str(quick_config(tmp_path / "station", "agebot-sm")))
    setup = win.page(PageId.SETUP)
    # finding 2: the README's method is the default, for AGEBOT's arm and a robot file
    assert setup.robot_key == "agebot-sm" and setup.method_name == "sm-distance-tilt"
    setup.set_choice(str(tmp_path.parent), "")            # not a robot: nothing changes
    setup.robot.setCurrentIndex(setup.robot.findData("agebot-pm"))
    assert setup.method_name == "pm-fk"
    assert not setup.rounds.isChecked() and not setup.rounds.isEnabled()   # finding 11
    setup.robot.setCurrentIndex(setup.robot.findData("agebot-sm"))
    assert setup.method_name == "sm-distance-tilt" and setup.rounds.isChecked()


def test_method_locked_while_connected(open_window, qtbot, tmp_path):
    """Finding 1: connected with sm-distance, the method cannot be changed behind it."""
    win = open_window(config_path=str(quick_config(tmp_path / "station", "agebot-sm")))
    setup = win.page(PageId.SETUP)
    setup.folder.setText(str(tmp_path / "s"))
    setup.set_choice("agebot-sm", "sm-distance")
    qtbot.mouseClick(setup.connect_button, Qt.MouseButton.LeftButton)
    qtbot.waitUntil(setup.is_complete, timeout=TIMEOUT)
    c = win.controller
    for w in (setup.robot, setup.method, setup.count, setup.rounds, setup.folder):
        assert not w.isEnabled() or not w.isVisibleTo(win), w
    setup.method.setFocus()
    qtbot.keyClick(setup.method, Qt.Key.Key_Down)
    qtbot.keyClick(setup.method, Qt.Key.Key_Up)
    assert setup.method_name == c.session.method == "sm-distance"
    assert "Disconnect" in setup.method.toolTip()
    qtbot.mouseClick(setup.disconnect_button, Qt.MouseButton.LeftButton)
    qtbot.waitUntil(lambda: c.session is None, timeout=TIMEOUT)
    wait_idle(qtbot, c)
    assert setup.method.isEnabled() and setup.robot.isEnabled()


def test_a_dead_simulator_is_survived(open_window, qtbot, tmp_path, answers):
    win = open_window(config_path=str(quick_config(tmp_path / "station", "agebot-sm")))
    c = win.controller
    setup = win.page(PageId.SETUP)
    ex = to_execute(win, qtbot, tmp_path / "s", 10, TIMEOUT)
    assert ex.picture is not None and ex.picture.isVisibleTo(win)   # the robot, live

    # the simulator dies while measuring: the fault dialog, then Retry goes on
    qtbot.mouseClick(ex.start_button, Qt.MouseButton.LeftButton)
    qtbot.waitUntil(lambda: len(c.session.measured) >= 2, timeout=TIMEOUT)
    _kill_simulator(c)
    qtbot.waitUntil(lambda: ex.fault_box is not None or not ex.running, timeout=TIMEOUT)
    said = []
    box = ex.fault_box
    assert box is not None, ex.status.text()
    said.append(box.informativeText())
    # issue 44: the simulator, not a drive, and every device, not one
    assert "simulator's process has stopped" in said[0] and "reset the drive" not in said[0]
    assert _marked(win, PageId.REFERENCE) and _marked(win, PageId.PLAN)
    qtbot.mouseClick(box.answer_buttons["retry"], Qt.MouseButton.LeftButton)

    def measured():
        b = ex.fault_box
        if b is not None and b.isVisible():     # a lost frame under load: Retry again
            said.append(b.informativeText())
            qtbot.mouseClick(b.answer_buttons["retry"], Qt.MouseButton.LeftButton)
        return ex.is_complete()

    qtbot.waitUntil(measured, timeout=2 * TIMEOUT)
    s = c.session
    assert c.sim.alive and not s.pending and len(s.measured) + len(s.skipped) == len(s.plan_poses)
    assert len(s.measured) >= len(s.plan_poses) - 1
    assert _marked(win, PageId.REFERENCE) and _marked(win, PageId.PLAN)
    said.append(ex.status.text())
    log = [ex.log.item(i).text() for i in range(ex.log.count())]
    said += log
    # Retry is not an abort: the log says the devices were connected anew
    assert any("to connect the devices anew" in t for t in log), log
    assert not any("after a fault" in t for t in log), log

    # dead again while idle: Connect on the setup page connects the same session anew,
    # without asking whether to resume it
    _kill_simulator(c)
    assert c.devices_lost
    assert win.go_to(PageId.SETUP)
    asked = len(answers["asked"])
    qtbot.mouseClick(setup.connect_button, Qt.MouseButton.LeftButton)
    qtbot.waitUntil(lambda: setup.is_complete() and c.session is not s, timeout=TIMEOUT)
    wait_idle(qtbot, c)
    assert len(answers["asked"]) == asked and c.sim.alive and c.session.resumed
    assert not c.devices_lost
    for pid in (PageId.REFERENCE, PageId.PLAN, PageId.EXECUTE):
        assert _marked(win, pid), pid
    said.append(setup.missing.text())
    text = "\n".join(said)
    assert "cable" not in text and "{'" not in text, text


def test_the_same_fault_a_third_time_on_a_pose_suggests_skip(open_window, qtbot):
    """A drive's reference-limit FAULT that comes back on every attempt at one pose (its
    tool below the floor on this robot) is not a flaky cable: the third time, the dialog
    says so and Skip is its default button. Another pose's or another fault's first
    time still defaults to Retry."""
    from types import SimpleNamespace

    from drivers.errors import DeviceError
    from station.gui.worker import FaultQuestion

    win = open_window()
    ex = win.page(PageId.EXECUTE)
    limit = DeviceError("drive node 3 reports FAULT: reference limit switch")
    asked = []

    def ask(index, error, attempt):
        req = FaultQuestion.Request(SimpleNamespace(index=index), error, attempt)
        ex.ask_fault(req)
        box = ex.fault_box
        asked.append((box.suggested, box.defaultButton() is box.answer_buttons["skip"],
                      "Skip is suggested" in box.informativeText()))
        qtbot.mouseClick(box.defaultButton(), Qt.MouseButton.LeftButton)
        assert req.event.is_set() and ex.fault_box is None
        return req.reply

    assert [ask(44, limit, k) for k in range(2)] == ["retry", "retry"]
    assert ask(12, DeviceError("draw-wire: no answer"), 0) == "retry"    # another pose
    assert ask(44, limit, 2) == "skip"
    assert asked[-1] == ("skip", True, True)
    assert asked[:3] == [("retry", False, False)] * 3
