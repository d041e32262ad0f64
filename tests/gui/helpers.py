"""Helpers of the wizard tests: screenshots, waiting for the workers."""
from __future__ import annotations

import os
import shutil
import subprocess
import time
from pathlib import Path

from PySide6.QtCore import QPoint, QPointF, QRect, QRectF
from PySide6.QtGui import QFontMetricsF, QPainter
from PySide6.QtWidgets import QApplication, QScrollArea

ROOT = Path(__file__).resolve().parents[2]
SHOTS = ROOT / "docs" / "screenshots"
SCREEN = (1366, 768)
#: the window on that screen under a desktop: less a taskbar (40 px) and the window
#: manager's title bar (32 px); what the operator's window really has
FRAMED = (SCREEN[0], SCREEN[1] - 72)


def _settle(seconds: float = 0.4) -> None:
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        QApplication.processEvents()
        time.sleep(0.02)


def screenshot(win, name: str, size=SCREEN) -> None:
    """Save a screenshot of ``win`` if asked to (``CALSTATION_SCREENSHOTS``):

    * ``1``: the widget itself at ``size``, 1366x768 unless said (``QWidget.grab``, no
      window frame); a page taller than that is saved once more scrolled to its end
      (``NAME-end.png``), the window left at 1366x768;
    * ``root``: the whole X screen with ``import -window root`` (ImageMagick), the
      window fitted to the screen as the wizard does it (under Xvfb at 1366x768 and
      a window manager, the frame included); a page taller than the screen is saved
      once more scrolled to its end (``NAME-end.png``).
    """
    mode = os.environ.get("CALSTATION_SCREENSHOTS")
    if not mode:
        return
    SHOTS.mkdir(parents=True, exist_ok=True)
    if mode != "root":
        main = win.isWindow() and win.inherits("QMainWindow")
        if main:
            win.resize(*size)
        _settle(0.2)
        area = win.stack.currentWidget().findChild(QScrollArea) if main else None
        if area is not None:
            area.verticalScrollBar().setValue(0)
            _settle(0.05)
        assert win.grab().save(str(SHOTS / f"{name}.png"))
        bar = area.verticalScrollBar() if area is not None else None
        if bar is not None and bar.maximum() > 0:
            bar.setValue(bar.maximum())
            _settle(0.05)
            assert win.grab().save(str(SHOTS / f"{name}-end.png"))
            bar.setValue(0)
        if main:
            win.resize(*SCREEN)
            _settle(0.05)
        return
    assert shutil.which("import"), "CALSTATION_SCREENSHOTS=root needs ImageMagick's import"
    main = win if win.inherits("QMainWindow") else win.parentWidget().window()
    if not getattr(main, "_shot_fitted", False):
        main.fit_to_screen()
        main._shot_fitted = True
        _settle(1.0)
        main.fit_to_screen()                  # now the window manager's frame is known
    page = main.stack.currentWidget()
    area = page.findChild(QScrollArea)
    if area is not None and win is main:
        area.verticalScrollBar().setValue(0)         # the page from its top
    _settle()
    subprocess.run(["import", "-window", "root", str(SHOTS / f"{name}.png")], check=True)
    if win is not main:
        return
    if area is not None and area.verticalScrollBar().maximum() > 0:
        bar = area.verticalScrollBar()
        bar.setValue(bar.maximum())
        _settle()
        subprocess.run(["import", "-window", "root", str(SHOTS / f"{name}-end.png")],
                       check=True)
        bar.setValue(0)
        _settle(0.1)


def wait_idle(qtbot, controller, timeout=30000) -> None:
    qtbot.waitUntil(lambda: not controller.jobs.busy, timeout=timeout)


def wait_measured(qtbot, page, session, timeout=180000) -> None:
    """Wait until the Execute ``page`` finished measuring; a question to the operator (a
    fault dialog nobody in the test answers) or a stopped run fails at once, saying what
    was asked or why it stopped, instead of waiting out ``timeout`` (a liveness bound)."""
    qtbot.waitUntil(lambda: page.is_complete() or page.fault_box is not None
                    or not page.running, timeout=timeout)
    box = page.fault_box
    assert box is None, (box.text(), box.informativeText())
    assert page.is_complete(), (page.status.text(), [e["message"] for e in session.events[-5:]])


def drawn_texts(widget, module) -> list[tuple[str, QRectF, QRectF | None]]:
    """Render ``widget`` (``grab``) and return every text its painting drew with
    ``module``'s ``QPainter``: ``(text, the rectangle it needs, the rectangle it was
    given or None)`` in the widget's coordinates."""
    drawn = []

    class Recorder(QPainter):
        def drawText(self, *args):
            t = self.transform()
            if isinstance(args[0], (QPointF, QPoint)) and len(args) == 2:
                pt, text = QPointF(args[0]), args[1]
                fm = QFontMetricsF(self.font())
                need = QRectF(pt.x(), pt.y() - fm.ascent(), fm.horizontalAdvance(text),
                              fm.ascent() + fm.descent())
                drawn.append((text, t.mapRect(need), None))
            elif isinstance(args[0], (QRectF, QRect)) and len(args) >= 3:
                given, flags, text = QRectF(args[0]), int(args[1]), args[2]
                need = self.boundingRect(given, flags, text)
                drawn.append((text, t.mapRect(need), t.mapRect(given)))
            else:
                raise AssertionError(f"drawText{args!r}: not recorded")
            return QPainter.drawText(self, *args)

    old = module.QPainter
    module.QPainter = Recorder
    try:
        widget.grab()
    finally:
        module.QPainter = old
    return drawn


def cut_texts(widget, module=None) -> list[str]:
    """The texts ``widget`` draws (:func:`drawn_texts`, the pictures' module unless
    said) cut: past the widget's edge, or larger than the rectangle they were drawn in
    (which clips them)."""
    if module is None:
        from station.gui import pictures as module
    edge = QRectF(widget.rect()).adjusted(-0.5, -0.5, 0.5, 0.5)
    return [text for text, need, given in drawn_texts(widget, module)
            if not edge.contains(need)
            or (given is not None and not given.adjusted(-1, -1, 1, 1).contains(need))]


def overlapping_texts(widget, module=None) -> list[tuple[str, str]]:
    """Pairs of texts ``widget`` draws over each other (:func:`drawn_texts`)."""
    if module is None:
        from station.gui import pictures as module
    drawn = [(text, need) for text, need, _ in drawn_texts(widget, module) if text.strip()]
    out = []
    for i, (a, ra) in enumerate(drawn):
        for b, rb in drawn[i + 1:]:
            both = ra.intersected(rb)
            if both.width() > 1 and both.height() > 1:
                out.append((a, b))
    return out


def to_execute(win, qtbot, folder, count: int, timeout: int = 60000):
    """Connect ``win`` (AGEBOT's arm, sm-distance, every pose planned at once) to a new
    session in ``folder``, capture the reference, plan ``count`` poses and show the
    Execute page, as an operator clicks through; returns that page."""
    from PySide6.QtCore import Qt

    from station.gui.pages import PageId

    c = win.controller
    setup = win.page(PageId.SETUP)
    setup.folder.setText(str(folder))
    setup.set_choice("agebot-sm", "sm-distance")
    setup.rounds.setChecked(False)          # one shot: every pose planned at once
    setup.count.setValue(count)
    qtbot.mouseClick(setup.connect_button, Qt.MouseButton.LeftButton)
    qtbot.waitUntil(setup.is_complete, timeout=timeout)
    qtbot.mouseClick(win.next_button, Qt.MouseButton.LeftButton)
    ref = win.page(PageId.REFERENCE)
    qtbot.mouseClick(ref.goto_button, Qt.MouseButton.LeftButton)
    wait_idle(qtbot, c)
    qtbot.mouseClick(ref.capture_button, Qt.MouseButton.LeftButton)
    qtbot.waitUntil(ref.is_complete, timeout=timeout)
    wait_idle(qtbot, c)
    qtbot.mouseClick(win.next_button, Qt.MouseButton.LeftButton)
    plan = win.page(PageId.PLAN)
    qtbot.waitUntil(lambda: plan.table.rowCount() >= count, timeout=timeout)
    wait_idle(qtbot, c)
    qtbot.mouseClick(win.next_button, Qt.MouseButton.LeftButton)
    return win.page(PageId.EXECUTE)
