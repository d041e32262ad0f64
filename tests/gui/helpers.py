"""Helpers of the wizard tests: screenshots, waiting for the workers."""
from __future__ import annotations

import os
from pathlib import Path

from PySide6.QtWidgets import QApplication

ROOT = Path(__file__).resolve().parents[2]
SHOTS = ROOT / "docs" / "screenshots"
SCREEN = (1366, 768)


def screenshot(win, name: str) -> None:
    """Save ``win`` (and its dialogs, given as ``win``) at 1366x768 if asked to."""
    if not os.environ.get("CALSTATION_SCREENSHOTS"):
        return
    SHOTS.mkdir(parents=True, exist_ok=True)
    if win.isWindow() and win.inherits("QMainWindow"):
        win.resize(*SCREEN)
    for _ in range(5):
        QApplication.processEvents()
    assert win.grab().save(str(SHOTS / f"{name}.png"))


def wait_idle(qtbot, controller, timeout=30000) -> None:
    qtbot.waitUntil(lambda: not controller.jobs.busy, timeout=timeout)
