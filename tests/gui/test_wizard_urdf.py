"""The wizard over a URDF robot (the M-10iA-like arm of fixtures/robots), measured by the
simulated station's motion capture (sm-markers): the URDF picked with Robot file..., its
links in two boxes (every link, the root and the deepest leaf by default), the methods a
URDF robot has at the station and the instrument for each; a chain that is not one said
in one line; Draw one leaving no empty folder behind; and a whole short session: a truth
drawn, connected, the markers live on the Reference page, the scout round planned, the
rounds measured (the markers in mm, the 3D stick figure with the points where the
estimate puts them and where they are seen), calibrated, exported with calibrated.urdf.

The session's station config has axes 12 times the default simulated station's and 3
frames a reading (:func:`station.simulation.urdf_sessions.urdf_config`); 20 poses to fit
(a scout round of 8 and a middle round of 8 before them): it takes some 45 s on 2 cores.
"""
from __future__ import annotations

import math
import os

import numpy as np
import pytest
from PySide6.QtCore import QSettings, Qt

from drivers.robot_file import urdf_ref
from drivers.sim.truth import load_truth
from station.gui.arm3d import ArmFigure
from station.gui.arm_drawing import stick
from station.gui.pages import PageId
from station.gui.pictures import BAD
from station.gui.widgets import ReadingsPanel, markers_text
from station.outputs.params_file import read_params
from tests.gui.helpers import ROOT, screenshot, wait_idle, wait_measured

URDF = ROOT / "fixtures" / "robots" / "m10ia-like.urdf"
HAYATI = ROOT / "fixtures" / "robots" / "ur5-like-hayati.toml"
REF = urdf_ref(URDF, "base_link", "tool0")
LINKS = ["world", "base_link", "link_1", "link_2", "link_3", "link_4", "link_5", "link_6",
         "flange", "tool0"]
TIMEOUT = 60000
SEED = 7                        # open_window's sim_seed: what Draw one draws with
COUNT = 20                      # poses to fit: a few more than eq. 60's 18


def _pick_urdf(setup, qtbot, monkeypatch, path=URDF):
    """Robot file... with ``path`` chosen in the file dialog."""
    from station.gui.pages import setup as setup_module

    monkeypatch.setattr(setup_module.QFileDialog, "getOpenFileName",
                        staticmethod(lambda *a, **k: (str(path), "")))
    qtbot.mouseClick(setup.robot_file_button, Qt.MouseButton.LeftButton)


def _methods(setup):
    return [setup.method.itemData(i) for i in range(setup.method.count())]


def _links(box):
    return [box.itemData(i) for i in range(box.count())]


def test_a_urdf_is_picked_with_its_links_and_the_station_s_methods(open_window, qtbot,
                                                                    monkeypatch, tmp_path):
    win = open_window()
    setup = win.page(PageId.SETUP)
    assert not setup.links_row.isVisible()            # AGEBOT's arm: no links to choose
    _pick_urdf(setup, qtbot, monkeypatch)
    # every link offered; the root link and the deepest leaf of the longest chain chosen
    assert setup.links_row.isVisible() and setup.instrument.isVisible()
    assert _links(setup.base_link) == LINKS and _links(setup.tip_link) == LINKS
    assert (setup.base_link.currentData(), setup.tip_link.currentData()) == ("world", "tool0")
    assert setup.robot_key == urdf_ref(URDF.resolve(), "world", "tool0")
    assert setup.robot_file and "m10ia-like.urdf" in setup.robot.currentText()
    # the methods of a URDF robot at the station, the markers first and chosen
    assert _methods(setup) == ["sm-markers", "sm-distance", "sm-distance-tilt"]
    assert setup.method_name == "sm-markers"
    assert "no reference" in setup.method_text.text()
    assert any("No truth for the simulated arm" in t for t in setup.missing_items())
    # another base link: the robot is that chain
    setup.base_link.setCurrentIndex(setup.base_link.findData("base_link"))
    assert setup.robot_key == urdf_ref(URDF.resolve(), "base_link", "tool0")
    assert setup._robot_error is None
    # the instrument the simulated station has for each method, once a truth is chosen
    from station.simulation.truth_cli import draw_truth_file

    truth = draw_truth_file(setup.robot_key, tmp_path / "t" / "truth.json", 3)
    setup.truth.setText(str(truth))
    text = setup.instrument.text()
    assert "motion capture" in text and "tool1, tool2, tool3" in text, text
    setup.method.setCurrentIndex(setup.method.findData("sm-distance-tilt"))
    assert "draw-wire" in setup.instrument.text() and "inclinometer" in setup.instrument.text()
    # a truth of another chain is said before connecting
    setup.base_link.setCurrentIndex(setup.base_link.findData("world"))
    assert any("truth file cannot be used for this robot" in t and "base_link to tool0" in t
               for t in setup.missing_items()), \
        setup.missing_items()
    # a robot file's arm has no sm-markers (a URDF robot's), and no link boxes
    _pick_urdf(setup, qtbot, monkeypatch, HAYATI)
    assert _methods(setup) == ["sm-distance", "sm-distance-tilt"]
    assert not setup.links_row.isVisible()
    # the URDF again: listed once, its links as left
    setup.set_choice(REF, "")
    assert setup.robot_key == urdf_ref(URDF.resolve(), "base_link", "tool0")
    assert sum("m10ia-like" in setup.robot.itemText(i) for i in range(setup.robot.count())) == 1


def test_the_wizard_opens_a_urdf_robot_with_the_given_links(qtbot, tmp_path, answers):
    """``app.py gui --robot ARM.urdf --base-link B --tip-link T`` arrives as the URDF
    robot's ref: the setup page shows that file with those links, sm-markers chosen."""
    from station.gui.app import create

    win = create(True, None, QSettings(str(tmp_path / "s.ini"), QSettings.Format.IniFormat),
                 robot=urdf_ref(os.path.relpath(URDF), "link_1", "flange"))
    qtbot.addWidget(win)
    try:
        setup = win.page(PageId.SETUP)
        assert (setup.base_link.currentData(), setup.tip_link.currentData()) == \
            ("link_1", "flange")
        assert setup.robot_key == urdf_ref(URDF.resolve(), "link_1", "flange")
        assert setup.method_name == "sm-markers" and setup._robot_error is None
    finally:
        win.controller.shutdown()


def test_a_chain_that_is_not_one_is_said_in_one_line(open_window, qtbot, monkeypatch,
                                                      tmp_path):
    win = open_window()
    setup = win.page(PageId.SETUP)
    _pick_urdf(setup, qtbot, monkeypatch)
    folder = tmp_path / "sessions" / "new"
    setup.folder.setText(str(folder))
    setup.base_link.setCurrentIndex(setup.base_link.findData("link_4"))
    setup.tip_link.setCurrentIndex(setup.tip_link.findData("link_2"))
    said = [t for t in setup.missing_items() if "link_2" in t]
    assert len(said) == 1 and "\n" not in said[0], setup.missing_items()
    assert "is not below the base link link_4" in said[0]
    assert said[0] in setup.missing.text()
    screenshot(win, "urdf-01-setup-wrong-chain")
    # the method box is not emptied; nothing can be drawn or connected
    assert _methods(setup) == ["sm-markers", "sm-distance", "sm-distance-tilt"]
    qtbot.mouseClick(setup.draw_truth_button, Qt.MouseButton.LeftButton)
    qtbot.mouseClick(setup.connect_button, Qt.MouseButton.LeftButton)
    wait_idle(qtbot, win.controller)
    assert win.controller.session is None and not setup.truth.text()
    assert not folder.exists() and not folder.parent.exists()
    # the same link for both: no movable joint between them
    setup.tip_link.setCurrentIndex(setup.tip_link.findData("link_4"))
    assert any("no movable joint between link_4 and link_4" in t
               for t in setup.missing_items()), setup.missing_items()
    # a chain again: the message goes
    setup.base_link.setCurrentIndex(setup.base_link.findData("base_link"))
    setup.tip_link.setCurrentIndex(setup.tip_link.findData("tool0"))
    assert not any("cannot be calibrated" in t for t in setup.missing_items())


def test_draw_one_leaves_no_empty_session_folder(open_window, qtbot, monkeypatch, tmp_path):
    win = open_window()
    setup = win.page(PageId.SETUP)
    setup.set_choice(REF, "sm-markers")
    # drawn: the truth and its true URDF in the session folder
    folder = tmp_path / "a" / "session"
    setup.folder.setText(str(folder))
    qtbot.mouseClick(setup.draw_truth_button, Qt.MouseButton.LeftButton)
    assert setup.truth.text() == str(folder / "sim-truth.json")
    assert sorted(p.name for p in folder.iterdir()) == ["sim-truth-true.urdf",
                                                        "sim-truth.json"]
    t = load_truth(folder / "sim-truth.json")
    assert t.robot == "urdf" and t.seed == SEED and len(t.points) == 3
    assert (t.spec.base_link, t.spec.tip_link) == ("base_link", "tool0")
    assert not any("truth" in m for m in setup.missing_items()), setup.missing_items()
    # a draw that fails (here: the disk) leaves none of the folders it made
    from station.simulation import truth_cli

    def fails(*a, **k):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(truth_cli, "draw_truth_file", fails)
    setup.truth.setText("")
    folder = tmp_path / "b" / "c" / "session"
    setup.folder.setText(str(folder))
    qtbot.mouseClick(setup.draw_truth_button, Qt.MouseButton.LeftButton)
    assert not (tmp_path / "b").exists() and not setup.truth.text()
    assert any(m.startswith("No truth drawn") for m in setup.missing_items())
    # an existing folder is kept as it was
    folder = tmp_path / "kept"
    folder.mkdir()
    setup.folder.setText(str(folder))
    qtbot.mouseClick(setup.draw_truth_button, Qt.MouseButton.LeftButton)
    assert folder.is_dir() and not list(folder.iterdir())


def test_the_readings_say_a_marker_not_seen(qtbot):
    panel = ReadingsPanel(["qm1", "m1_x", "m1_y", "m1_z", "m2_x", "m2_y", "m2_z"])
    qtbot.addWidget(panel)
    panel.set_values({"qm1": 0.5, "m1_x": 1.25, "m1_y": -0.5, "m1_z": 2.0,
                      "m2_x": math.nan, "m2_y": math.nan, "m2_z": math.nan})
    assert panel.text_of("m1_x") == "1250.000 mm" and panel.text_of("m1_y") == "-500.000 mm"
    assert panel.text_of("m2_x") == "not seen"
    text = markers_text({"m1_x": 1.25, "m1_y": -0.5, "m1_z": 2.0, "m2_x": math.nan,
                         "m2_y": math.nan, "m2_z": math.nan}, ("tool1", "tool2"))
    assert text == "m1 tool1 (1250, -500, 2000) mm; m2 tool2 not seen"


@pytest.mark.slow       # a whole session through the wizard (30 s on 2 cores): CI runs it
def test_a_urdf_session_in_the_wizard(open_window, qtbot, tmp_path, answers):
    from station.simulation.truth_cli import draw_truth_file
    from station.simulation.urdf_sessions import urdf_config

    # the station config of the truth Draw one will draw (the same seed: the same room)
    pre = draw_truth_file(REF, tmp_path / "pre" / "truth.json", SEED)
    cfg = urdf_config(load_truth(pre), REF, tmp_path / "pre", speed=12.0, frames=3)
    win = open_window(config_path=str(cfg))
    c = win.controller
    folder = tmp_path / "urdf"

    # 1 setup: the URDF with its chain, Draw one, the motion capture among the devices
    setup = win.page(PageId.SETUP)
    setup.folder.setText(str(folder))
    setup.set_choice(REF, "sm-markers")
    assert setup.method_name == "sm-markers"
    qtbot.mouseClick(setup.draw_truth_button, Qt.MouseButton.LeftButton)
    assert setup.truth.text() == str(folder / "sim-truth.json")
    assert "tool1, tool2, tool3" in setup.instrument.text()
    setup.count.setValue(COUNT)
    screenshot(win, "urdf-01-setup-choose")
    qtbot.mouseClick(setup.connect_button, Qt.MouseButton.LeftButton)
    qtbot.waitUntil(setup.is_complete, timeout=TIMEOUT)
    assert "motion capture" in setup.devices.states and all(setup.devices.states.values())
    row = next(r for r in range(setup.devices.rowCount())
               if setup.devices.item(r, 0).text() == "motion capture")
    # at home the tool faces sideways: the cameras above see no marker, and say so
    assert setup.devices.item(row, 2).text() == \
        "m1 tool1 not seen; m2 tool2 not seen; m3 tool3 not seen"
    s = c.session
    assert s.method == "sm-markers" and s.serial and not s.needs_reference
    assert not win.page(PageId.REFERENCE).is_complete()      # not ticked before it is seen
    screenshot(win, "urdf-01-setup")

    # 2 reference: none to capture; the markers live, the stick figure from the URDF
    qtbot.mouseClick(win.next_button, Qt.MouseButton.LeftButton)
    ref = win.page(PageId.REFERENCE)
    assert win.current == PageId.REFERENCE and ref.is_complete()
    fig = ref.picture
    assert isinstance(fig, ArmFigure) and fig.labels == ("tool1", "tool2", "tool3")
    # the picture, the readings table and the status line are each updated by the live
    # timer: wait for all three (a loaded machine may show one a tick before the others)
    qtbot.waitUntil(lambda: fig.readings is not None and fig.qm is not None
                    and ref.readings.text_of("m1_x") == "not seen"
                    and "0 of the 3" in ref.status.text(), timeout=10000)
    assert ("not seen: tool1, tool2, tool3", BAD) in fig.marker_lines()
    # the wrist turned up: the cameras see the markers (in mm), the first step is done
    c.move_to([0.0, 0.0, 0.0, 0.0, math.pi / 2, 0.0])
    wait_idle(qtbot, c)
    qtbot.waitUntil(lambda: fig.readings is not None and np.isfinite(fig.readings).all()
                    and ref.readings.text_of("m1_x").endswith(" mm")
                    and "sees the 3 markers" in ref.status.text(), timeout=10000)
    assert fig.step == 1
    assert fig.marker_lines()[0][0] == "motion capture: 3 of 3 points seen"
    arm = stick(s.robot, fig.qm, fig.xi)
    assert len(arm.joints) == 6 and np.allclose(arm.points[0], 0.0)
    assert np.allclose(arm.tool, s.robot.frames(fig.qm, fig.xi)[0])
    qtbot.waitUntil(lambda: fig.draws >= 1 and fig._drawn_key == fig._key(), timeout=5000)
    assert fig.frame is None            # no pose yet: the instrument's frame not known
    screenshot(win, "urdf-02-reference")

    # 3 plan: the scout round
    qtbot.mouseClick(win.next_button, Qt.MouseButton.LeftButton)
    plan = win.page(PageId.PLAN)
    qtbot.waitUntil(lambda: plan.table.rowCount() > 0, timeout=TIMEOUT)
    wait_idle(qtbot, c)
    assert all(p.round == 0 for p in s.plan_poses) and plan.plot.count == len(s.plan_poses)
    assert "scout round" in plan.counts.text() and not plan.table.isColumnHidden(2)
    screenshot(win, "urdf-03-plan")

    # 4 execute: the rounds measured; the markers in mm, the estimate's points drawn
    qtbot.mouseClick(win.next_button, Qt.MouseButton.LeftButton)
    ex = win.page(PageId.EXECUTE)
    qtbot.mouseClick(ex.start_button, Qt.MouseButton.LeftButton)
    qtbot.waitUntil(lambda: "markers (the last pose recorded): m1 tool1" in ex.current.text(),
                    timeout=TIMEOUT)
    # once the scout round placed the instrument: the points drawn live, as estimated and
    # as seen
    qtbot.waitUntil(lambda: ex.picture.frame is not None and len(s.measured) > 10,
                    timeout=TIMEOUT)
    screenshot(win, "urdf-04-execute-running")
    wait_measured(qtbot, ex, s, timeout=240000)
    assert s.rounds_complete and len(s.measured) + len(s.skipped) >= COUNT + 16
    text = ex.readings.text_of("m1_x")
    assert text.endswith(" mm") or text == "not seen", text
    pic = ex.picture
    assert isinstance(pic, ArmFigure) and pic.labels
    qtbot.waitUntil(lambda: pic.frame is not None, timeout=5000)
    assert pic.points.shape == (3, 3) and 0.02 < np.linalg.norm(pic.points, axis=1).max() < 0.2
    qtbot.waitUntil(lambda: pic._drawn_key == pic._key(), timeout=5000)
    screenshot(win, "urdf-04-execute")

    # 5 calibrate: the held-out points' error down
    qtbot.mouseClick(win.next_button, Qt.MouseButton.LeftButton)
    cal = win.page(PageId.CALIBRATE)
    qtbot.waitUntil(lambda: not cal.running, timeout=TIMEOUT)
    assert cal.is_complete(), cal.status.text()
    val = {v["channel"]: v for v in s.validation}
    assert val["marker"]["rms_after"] < val["marker"]["rms_before"] / 10, val
    screenshot(win, "urdf-05-calibrate")

    # 6 export: the parameter file, the report and calibrated.urdf listed
    qtbot.mouseClick(win.next_button, Qt.MouseButton.LeftButton)
    exp = win.page(PageId.EXPORT)
    qtbot.waitUntil(exp.is_complete, timeout=TIMEOUT)
    assert exp.urdf.isVisible() and exp.urdf.text() == str(folder / "calibrated.urdf")
    assert (folder / "calibrated.urdf").stat().st_size > 500
    doc = read_params(folder / "params.json")
    assert doc["method"] == "sm-markers" and "checksum OK" in exp.verified.text()
    screenshot(win, "urdf-06-export")

    # the folder opened again in a new window: resumed with the trace's chain (the
    # fixture URDF is listed with its default links, world to tool0)
    measured = len(s.measured)
    win.close()
    win = open_window(config_path=str(cfg))
    setup = win.page(PageId.SETUP)
    assert setup.robot.findData(urdf_ref(URDF.resolve(), "world", "tool0")) >= 0
    setup.folder.setText(str(folder))
    qtbot.mouseClick(setup.connect_button, Qt.MouseButton.LeftButton)
    qtbot.waitUntil(lambda: setup.is_complete() or bool(not setup._connecting
                                                        and setup._error), timeout=TIMEOUT)
    assert setup.is_complete(), setup.missing_items()
    assert answers["asked"] and answers["asked"][-1][0] == "Resume the session?"
    assert setup.robot_key == urdf_ref(URDF.resolve(), "base_link", "tool0")
    assert setup.truth.text() == str(folder / "sim-truth.json")
    assert win.controller.session.resumed and len(win.controller.session.measured) == measured


def test_a_urdf_robot_measured_by_the_station_s_own_sensors(open_window, qtbot, tmp_path):
    """sm-distance-tilt on a URDF robot, as on a robot file's arm: the reference with the
    URDF's stick figure, the draw-wire and the inclinometer; the poses planned."""
    from station.simulation.truth_cli import draw_truth_file
    from station.simulation.urdf_sessions import urdf_config

    truth = draw_truth_file(REF, tmp_path / "pre" / "truth.json", SEED)
    cfg = urdf_config(load_truth(truth), REF, tmp_path / "pre", speed=12.0, frames=3)
    win = open_window(config_path=str(cfg))
    c = win.controller
    setup = win.page(PageId.SETUP)
    setup.folder.setText(str(tmp_path / "dt"))
    setup.set_choice(REF, "sm-distance-tilt")
    setup.truth.setText(str(truth))
    text = setup.instrument.text()
    assert "draw-wire" in text and "inclinometer" in text, text
    setup.count.setValue(12)
    qtbot.mouseClick(setup.connect_button, Qt.MouseButton.LeftButton)
    qtbot.waitUntil(setup.is_complete, timeout=TIMEOUT)
    s = c.session
    assert s.method == "sm-distance-tilt" and s.needs_reference
    qtbot.mouseClick(win.next_button, Qt.MouseButton.LeftButton)
    ref = win.page(PageId.REFERENCE)
    fig = ref.picture
    assert isinstance(fig, ArmFigure) and not fig.labels
    qtbot.mouseClick(ref.goto_button, Qt.MouseButton.LeftButton)
    wait_idle(qtbot, c)
    qtbot.waitUntil(lambda: fig.step == 1 and fig.qm is not None, timeout=10000)
    arm = stick(s.robot, fig.qm, fig.xi)
    assert len(arm.joints) == 6
    assert np.allclose(arm.tool[:3, 3], s.robot.fk(fig.qm, fig.xi)[0, :3])
    qtbot.mouseClick(ref.capture_button, Qt.MouseButton.LeftButton)
    qtbot.waitUntil(ref.is_complete, timeout=TIMEOUT)
    wait_idle(qtbot, c)
    qtbot.mouseClick(win.next_button, Qt.MouseButton.LeftButton)
    plan = win.page(PageId.PLAN)
    qtbot.waitUntil(lambda: plan.table.rowCount() >= 12, timeout=TIMEOUT)
    wait_idle(qtbot, c)
    assert plan.plot.count == len(s.plan_poses)
