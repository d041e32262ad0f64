"""``python app.py`` / ``python app.py gui [--simulate] [--config FILE]``: the wizard."""
from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

from calibration.errors import ConfigError


def create(simulate: bool = False, config: str | None = None, settings=None,
           robot: str | None = None, truth: str | None = None):
    """The controller and main window (the Qt application must exist); ``robot``
    preselected on the setup page (a built-in name, a robot file or a URDF robot's
    :func:`drivers.robot_file.urdf_ref`, its links chosen)."""
    from PySide6.QtCore import QSettings

    from station.gui.controller import Controller
    from station.gui.pages import PageId
    from station.gui.window import MainWindow

    if settings is None:
        settings = QSettings("calstation", "station")
    controller = Controller(simulate=simulate, config_path=config, settings=settings,
                            truth_path=truth)
    window = MainWindow(controller)
    if robot:
        setup = window.page(PageId.SETUP)
        setup.set_choice(robot, "")
        if setup.robot_key is None or (setup.robot_key != robot and not setup.robot_file):
            raise ConfigError(f"--robot {robot}: not a robot the wizard knows (agebot-sm, "
                              "agebot-pm, a robot file or a URDF)")
    return window


def main(args: argparse.Namespace) -> int:
    from station.doctor import gui_problem

    check = getattr(args, "check", False)
    problem = gui_problem() if sys.platform.startswith("linux") else None
    if problem and check:
        raise SystemExit(problem)
    try:
        from PySide6.QtCore import QTimer
        from PySide6.QtWidgets import QApplication
    except ImportError as e:  # a broken install
        raise SystemExit(f"the GUI needs PySide6 ({e}): pip install -e .") from None
    if (sys.platform.startswith("linux") and not os.environ.get("QT_QPA_PLATFORM")
            and not os.environ.get("DISPLAY") and not os.environ.get("WAYLAND_DISPLAY")):
        # Qt would abort the process with a core dump; say it in one line instead
        raise SystemExit("no display for the wizard (DISPLAY and WAYLAND_DISPLAY are unset): "
                         "run it in a desktop session, or headless use "
                         "'python app.py run --simulate --robot R --method M --out DIR'")
    if problem:             # Qt would abort the process (rc 134) naming another library
        raise SystemExit(problem)
    if check:
        print("the wizard can run here (a display, and Qt's platform plugin finds its "
              "libraries)")
        return 0
    config = getattr(args, "config", None)
    if config:
        if not Path(config).is_file():
            raise ConfigError(f"no such station config: {config}", source=config)
    app = QApplication.instance() or QApplication(sys.argv[:1])
    app.setApplicationName("Calibration station")
    app.setOrganizationName("calstation")
    robot = getattr(args, "robot", None)
    from drivers.robot_file import split_urdf_ref
    from drivers.sim.serial_robot import is_robot_file

    ref = split_urdf_ref(robot) if robot else None
    path = ref[0] if ref is not None else robot       # a URDF robot: its file
    if robot and is_robot_file(robot) and not Path(path).is_file():
        raise ConfigError(f"no such robot file: {path}", source=path)
    window = create(bool(getattr(args, "simulate", False)), config,
                    robot=robot, truth=getattr(args, "truth", None))
    window.show_fitted()
    QTimer.singleShot(0, window.offer_resume)
    return int(app.exec())
