"""Helpers of the wizard tests: screenshots, waiting for the workers."""
from __future__ import annotations

import os
import shutil
import subprocess
import time
from pathlib import Path

from PySide6.QtWidgets import QApplication, QScrollArea

ROOT = Path(__file__).resolve().parents[2]
SHOTS = ROOT / "docs" / "screenshots"
SCREEN = (1366, 768)


def _settle(seconds: float = 0.4) -> None:
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        QApplication.processEvents()
        time.sleep(0.02)


def screenshot(win, name: str) -> None:
    """Save a screenshot of ``win`` if asked to (``CALSTATION_SCREENSHOTS``):

    * ``1``: the widget itself at 1366x768 (``QWidget.grab``, no window frame);
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
        if win.isWindow() and win.inherits("QMainWindow"):
            win.resize(*SCREEN)
        for _ in range(5):
            QApplication.processEvents()
        assert win.grab().save(str(SHOTS / f"{name}.png"))
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
