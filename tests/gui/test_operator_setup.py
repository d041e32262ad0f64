"""The Setup page as an operator meets it (issue 44): the first Connect on a new machine
makes the wizard's own sessions folder; while connected the robot cannot be changed,
Robot file... included, and the page says that Disconnect is needed."""
from __future__ import annotations

from pathlib import Path

from station.gui.pages import PageId
from station.gui.pages.setup_choices import default_folder
from tests.gui.helpers import wait_idle


def test_the_first_connect_on_a_new_machine_makes_the_sessions_folder(open_window, qtbot,
                                                                      tmp_path, monkeypatch):
    monkeypatch.setattr(Path, "home", classmethod(lambda cls: tmp_path / "home"))
    (tmp_path / "home").mkdir()
    win = open_window()
    setup = win.page(PageId.SETUP)
    setup.folder.setText(default_folder())  # under the patched home
    assert not (tmp_path / "home" / "calstation-sessions").exists()
    setup.connect_session()
    wait_idle(qtbot, win.controller)
    qtbot.waitUntil(lambda: win.controller.session is not None, timeout=30000)
    assert (tmp_path / "home" / "calstation-sessions").is_dir()
    assert "does not exist" not in setup.missing.text()
    # connected: the robot is fixed, the Robot file button too, and the page says why
    assert not setup.robot.isEnabled() and not setup.robot_file_button.isEnabled()
    assert "Disconnect" in setup.robot_file_button.toolTip()
    qtbot.waitUntil(lambda: "Press Next" in setup.missing.text(), timeout=30000)
    assert "Disconnect first" in setup.missing.text()


def test_a_folder_typed_under_a_missing_parent_is_still_refused(open_window, qtbot, tmp_path):
    win = open_window()
    setup = win.page(PageId.SETUP)
    setup.folder.setText(str(tmp_path / "no" / "such" / "place"))
    setup.connect_session()
    wait_idle(qtbot, win.controller)
    qtbot.waitUntil(lambda: "does not exist" in setup.missing.text(), timeout=30000)
    assert win.controller.session is None and not (tmp_path / "no").exists()



def test_how_poses_are_planned_is_said_not_an_unticked_box(open_window):
    win = open_window()
    setup = win.page(PageId.SETUP)
    setup.robot.setCurrentIndex(setup.robot.findData("agebot-pm"))
    assert not setup.rounds.isVisibleTo(win) and setup.rounds_note.isVisibleTo(win)
    assert "rounds" in setup.rounds_note.text()
    ur5 = next(setup.robot.itemData(i) for i in range(setup.robot.count())
               if "ur5-like-hayati" in str(setup.robot.itemData(i)))
    setup.robot.setCurrentIndex(setup.robot.findData(ur5))
    assert not setup.rounds.isVisibleTo(win) and "at once" in setup.rounds_note.text()
    setup.robot.setCurrentIndex(setup.robot.findData("agebot-sm"))
    assert setup.rounds.isVisibleTo(win) and setup.rounds.isChecked()
    assert not setup.rounds_note.isVisibleTo(win)
