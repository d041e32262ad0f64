"""What the operator found cut or scrolling twice at 1366x768: the live pictures'
captions (the Execute page's "rail (seen fron", the bubble level's), the results'
tables scrolling inside the scrolling page, and the identifiability strip's 45 columns
in one row. (A robot file's Reference buttons half off the screen: test_wizard_arm.)
A URDF robot's Execute and Reference pages with the motion capture's markers in sight."""
from __future__ import annotations

import math
from types import SimpleNamespace

import pytest
import numpy as np
from PySide6.QtCore import QPoint, QPointF, QRect, Qt
from PySide6.QtGui import QWheelEvent
from PySide6.QtWidgets import QApplication, QScrollArea

from calibration.robots import get_robot
from drivers.robot_file import load_robot_file
from station.gui.pages import PageId
from station.outputs.report_context import IDENT_SYMBOL, group_of
from tests.gui.helpers import FRAMED, ROOT, SCREEN, cut_texts, overlapping_texts

HAYATI = ROOT / "fixtures" / "robots" / "ur5-like-hayati.toml"
URDF = ROOT / "fixtures" / "robots" / "m10ia-like.urdf"
REFERENCE_QM = [36.0, 149.0534, -171.8204, -134.3126]     # AGEBOT's arm, u
AWAY_QM = [39.217, 144.389, -169.524, -137.556]           # 75 mm from it
READABLE = 15         # the identifiability strip's parameters a row at most


@pytest.fixture
def window(open_window):
    """The wizard over simulated devices at 1366x768 (conftest's open_window)."""
    return open_window()


def _show(qtbot, win, pid):
    """The page ``pid`` in the window, whether or not the steps before it are done."""
    page = win.page(pid)
    win.stack.setCurrentWidget(page)
    qtbot.wait(100)
    return page


def _agebot_sm():
    robot = get_robot("agebot-sm")
    return SimpleNamespace(serial=False, robot=robot, nominal=robot.nominal,
                           reference_qm=REFERENCE_QM)


@pytest.mark.parametrize("robot", ["agebot-sm", "agebot-pm"])
def test_the_execute_page_s_picture_cuts_no_caption(window, qtbot, robot):
    """The Execute page at 1366x768: the arm's side view ("rail (seen from above)" was
    cut to "rail (seen fron", its carriage's z too) and the wrist's bubble level (its
    caption and its reading were cut) say every text whole."""
    ex = _show(qtbot, window, PageId.EXECUTE)
    if robot == "agebot-sm":
        s = _agebot_sm()
        channels = ["qm1", "qm2", "qm3", "qm4", "tilt", "distance"]
    else:
        s = SimpleNamespace(serial=False, robot=SimpleNamespace(name=robot), nominal=None,
                            reference_qm=None)
        channels = ["qm1", "qm2", "qm3", "roll", "pitch", "yaw"]
    ex.readings.set_channels(channels)
    ex._build_picture(s)
    qtbot.wait(200)
    pic = ex.picture
    assert pic.isVisible() and pic.width() < 500          # a third of the row, or so
    if robot == "agebot-sm":
        # the rail's carriage at 871 mm, 0 (on the floor) and short of it: z -0.5 mm
        for qm in (AWAY_QM, [0.0, 100, -120, -100], [-0.0225, 150, -170, -130]):
            pic.set_state(qm=qm)
            assert not cut_texts(pic), (qm, cut_texts(pic))
            assert not overlapping_texts(pic), (qm, overlapping_texts(pic))
    else:
        for roll, pitch in ((None, None), (0.01, -0.005), (math.radians(17.6),
                                                            math.radians(-14.1))):
            if roll is not None:
                pic.set_angles(roll, pitch)
            assert not cut_texts(pic), (roll, pitch, cut_texts(pic))
            assert not overlapping_texts(pic), (roll, pitch, overlapping_texts(pic))


@pytest.mark.parametrize("size", [(380, 280), (560, 420), (714, 532), (900, 560)])
def test_the_reference_pictures_cut_no_text_at_any_size(qtbot, size):
    """The pictures with the reference's steps, from their smallest to a wide page (the
    Reference page gives them some 714 x 532 px at 1366x768): no text cut, none over
    another."""
    from station.gui.level_picture import LevelPicture
    from station.gui.pictures import ArmPicture

    s = _agebot_sm()
    arm = ArmPicture(s.robot, s.nominal)
    level = LevelPicture()
    for pic in (arm, level):
        qtbot.addWidget(pic)
        pic.resize(*size)
    assert arm.size().toTuple() == size
    arm.set_state(target_qm=s.reference_qm)
    for state in (dict(qm=AWAY_QM),                         # far from the mark
                  dict(qm=s.reference_qm),                  # there: attach the cable
                  dict(captured=True, captured_qm=AWAY_QM)):    # captured far from it
        arm.set_state(**state)
        assert not cut_texts(arm), (state, cut_texts(arm))
        assert not overlapping_texts(arm), (state, overlapping_texts(arm))
    assert arm.warned
    for roll, pitch in ((3.0, -2.5), (0.5, 0.2), (-30.0, 25.0)):
        level.set_angles(math.radians(roll), math.radians(pitch))
        assert not cut_texts(level), (roll, pitch, cut_texts(level))
        assert not overlapping_texts(level), (roll, pitch, overlapping_texts(level))


@pytest.mark.parametrize("size", [(300, 240), (380, 424), (520, 424)])
def test_the_execute_pictures_cut_no_text_at_any_size(qtbot, size):
    """The Execute page's form of the pictures (no steps, the reference captured) from
    the smallest the page lets them be."""
    from station.gui.level_picture import LevelPicture
    from station.gui.pictures import ArmPicture

    s = _agebot_sm()
    arm = ArmPicture(s.robot, s.nominal, target_label="reference")
    level = LevelPicture()
    for pic in (arm, level):
        qtbot.addWidget(pic)
        pic.steps = []
        pic.setMinimumSize(300, 240)                # as the Execute page sets it
        pic.resize(*size)
    arm.set_state(target_qm=s.reference_qm, captured=True, captured_qm=s.reference_qm)
    for qm in (AWAY_QM, s.reference_qm, [0.0, 100, -120, -100]):
        arm.set_state(qm=qm)
        assert not cut_texts(arm), (qm, cut_texts(arm))
        assert not overlapping_texts(arm), (qm, overlapping_texts(arm))
    level.set_angles(math.radians(17.6), math.radians(-14.1))
    assert not cut_texts(level), cut_texts(level)
    assert not overlapping_texts(level), overlapping_texts(level)


def _urdf_markers():
    """A stand-in of a URDF robot's sm-markers session (the M-10iA-like arm, three markers
    on its tool), its estimate of the instrument's frame and the points made."""
    from drivers.robot_file import urdf_ref

    robot = get_robot(load_robot_file(urdf_ref(URDF, "base_link", "tool0")))
    xi = robot.nominal.copy()
    for name, v in (("base_x", 1.4), ("base_y", -1.9), ("base_z", 0.6), ("base_yaw", 2.2)):
        xi[robot.index(name)] = v
    points = np.array([[0.05, 0.02, 0.04], [-0.03, 0.05, 0.06], [0.0, -0.06, 0.05]])
    kind = SimpleNamespace(labels=("tool1", "tool2", "tool3"), last_estimate=(xi, points))
    return SimpleNamespace(method="sm-markers", serial=True, robot=robot, nominal=robot.nominal,
                           reference_qm=None, kind=kind, needs_reference=False,
                           reference_target=lambda: (None, "no reference", ""))


def _in_sight(widget, area) -> bool:
    top_left = widget.mapTo(area.viewport(), QPoint(0, 0))
    return area.viewport().rect().contains(QRect(top_left, widget.size()))


@pytest.mark.parametrize("size", [SCREEN, FRAMED])
def test_a_urdf_robot_s_execute_and_reference_pages_fit(window, qtbot, size):
    """A URDF robot measured by a motion capture at 1366x768 (and less a taskbar and a
    title bar): the Execute page's 15 readings (6 joints, 3 markers' x, y, z) and its 3D
    picture, the Reference page's jog panel, markers and picture, each in sight without
    scrolling the page; a marker not seen reads "not seen"."""
    from station.gui.arm3d import ArmFigure, show_estimate
    from station.gui.widgets import marker_channels

    s = _urdf_markers()
    window.resize(*size)
    ex = _show(qtbot, window, PageId.EXECUTE)
    ex.readings.set_channels([f"qm{i}" for i in range(1, 7)] + list(marker_channels(3)))
    ex._build_picture(s)
    pic = ex.picture
    assert isinstance(pic, ArmFigure) and pic.labels == ("tool1", "tool2", "tool3")
    show_estimate(pic, s)
    qm = [0.3, 0.2, -0.1, 0.4, 1.2, 0.0]
    T = s.robot.frames(np.array([qm]), s.kind.last_estimate[0])[0]
    seen = s.kind.last_estimate[1] @ T[:3, :3].T + T[:3, 3]
    values = {f"qm{i + 1}": v for i, v in enumerate(qm)}
    values.update({f"m{k + 1}_{a}": (math.nan if k == 1 else float(seen[k, j]))
                   for k in range(3) for j, a in enumerate("xyz")})
    ex._values(values)
    pic.set_state(qm=qm)            # as _show_robot does with a session's readings
    pic.set_markers(values)
    assert ex.readings.text_of("m2_y") == "not seen"
    assert ex.readings.text_of("m1_x") == f"{seen[0, 0] * 1e3:.3f} mm"
    assert any(text == "not seen: tool2" for text, _ in pic.marker_lines())
    # the lines over the picture never squeeze the 3D axes (a line wider than the
    # picture collapsed them to a dot): with the estimate and before it
    for est in (s.kind.last_estimate, (None, None)):
        pic.set_estimate(*est)
        qtbot.waitUntil(lambda: pic._drawn_key == pic._key(), timeout=5000)
        pic.canvas.draw()
        box = pic.ax.get_position()
        assert box.width > 0.6 and box.height > 0.6, (size, est[0] is None, box)
    show_estimate(pic, s)
    qtbot.waitUntil(lambda: pic.draws >= 1 and pic._drawn_key == pic._key(), timeout=5000)
    area = ex.findChild(QScrollArea)
    qtbot.wait(100)
    assert area.verticalScrollBar().maximum() == 0, size
    assert area.horizontalScrollBar().maximum() == 0, size
    for w in (ex.readings, pic, ex.status, ex.start_button):
        assert _in_sight(w, area), (size, w)

    ref = _show(qtbot, window, PageId.REFERENCE)
    ref._build(s)
    ref._values(values)
    assert ref.readings.text_of("m2_x") == "not seen"
    qtbot.wait(200)
    area = ref.findChild(QScrollArea)
    try:                          # the 3D picture's first paint takes a while
        qtbot.waitUntil(lambda: area.verticalScrollBar().maximum() == 0, timeout=3000)
    except qtbot.TimeoutError:
        pass
    assert area.verticalScrollBar().maximum() == 0, size
    for w in (ref.jog.stop, ref.readings, ref.picture, ref.status):
        assert _in_sight(w, area), (size, w)
    window.resize(*SCREEN)


def _ur5_trace(path, method="sm-distance-tilt"):
    from station.recording.trace_writer import write_trace
    from station.simulation import tracegen_serial

    robot = get_robot(load_robot_file(HAYATI))
    header, reference, poses = tracegen_serial.generate(
        robot, method, robot.nominal, seed=3, noise={"distance": 1e-5, "tilt": 1e-4})
    write_trace(path, header, reference, poses)
    return path


def _calibrated_ur5(window, qtbot, tmp_path):
    """The Offline page at 1366x768 with a UR5-like arm's trace calibrated (44
    parameters), laid out: ``(page, its scroll area, the result)``."""
    assert window.go_to(PageId.OFFLINE)
    off = window.page(PageId.OFFLINE)
    assert off.open_trace(_ur5_trace(tmp_path / "ur5.jsonl"))
    qtbot.mouseClick(off.calibrate_button, Qt.MouseButton.LeftButton)
    qtbot.waitUntil(lambda: off.outcome is not None, timeout=30000)
    area = off.findChild(QScrollArea)
    # the first paint of the plots takes a while; then the page is laid out anew
    qtbot.waitUntil(lambda: area.verticalScrollBar().maximum() > 0, timeout=10000)
    qtbot.wait(100)
    res = off.outcome.result
    assert len(res.names) > 40
    return off, area, res


def test_a_robot_file_s_results_tables_scroll_with_the_page(window, qtbot, tmp_path):
    """A UR5-like arm's calibration at 1366x768: the strip and the tables are as tall as
    their rows and as wide as their columns, none scrolls on its own (the parameter
    table, 48 rows, had its own scroll bar inside the page's); the page scrolls, the
    wheel over a table scrolls it."""
    off, area, res = _calibrated_ur5(window, qtbot, tmp_path)
    view = off.view
    assert view.params.rowCount() > 40
    for t in (view.strip, view.params, view.validation):
        for bar in (t.verticalScrollBar(), t.horizontalScrollBar()):
            assert bar.maximum() == 0 and not bar.isVisible(), t
        rows = sum(t.rowHeight(r) for r in range(t.rowCount()))
        assert t.viewport().height() >= rows, (t, t.viewport().height(), rows)
    for t in (view.params, view.validation):
        assert t.viewport().width() >= t.horizontalHeader().length() - 1, t
    assert area.horizontalScrollBar().maximum() == 0
    bar = area.verticalScrollBar()
    t = view.params
    bar.setValue(t.mapTo(off.body, QPoint(0, 0)).y())
    qtbot.wait(50)
    before = bar.value()
    pos = QPointF(t.viewport().width() / 2, 10)
    ev = QWheelEvent(pos, t.viewport().mapToGlobal(pos), QPoint(0, 0), QPoint(0, -120),
                     Qt.MouseButton.NoButton, Qt.KeyboardModifier.NoModifier,
                     Qt.ScrollPhase.NoScrollPhase, False)
    QApplication.sendEvent(t.viewport(), ev)
    qtbot.wait(50)
    assert bar.value() > before


def test_a_robot_file_s_identifiability_strip_wraps(window, qtbot, tmp_path):
    """A UR5-like arm's 44 parameters at 1366x768: the identifiability strip (one column
    a parameter, most off to the side) wraps into rows of at most READABLE parameters,
    all in sight sideways, each parameter's symbol kept; narrower, into more rows."""
    off, area, res = _calibrated_ur5(window, qtbot, tmp_path)
    strip = off.view.strip
    expected = {n: IDENT_SYMBOL[group_of(st)] for n, st in zip(res.names, res.status)}

    def fits():
        return strip.horizontalHeader().length() <= strip.viewport().width()

    assert 0 < strip.columnCount() <= READABLE
    qtbot.waitUntil(fits, timeout=5000)
    assert strip.rowCount() == 2 * math.ceil(len(res.names) / strip.columnCount())
    assert strip.symbols() == expected
    wide = strip.columnCount()
    window.resize(1000, 700)
    qtbot.waitUntil(lambda: fits() and strip.columnCount() < wide, timeout=5000)
    assert strip.symbols() == expected
    assert strip.verticalScrollBar().maximum() == 0
    assert area.horizontalScrollBar().maximum() == 0
    window.resize(*SCREEN)
