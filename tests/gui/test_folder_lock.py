"""The wizard's session takes the folder's lock: a folder in use by another session
is refused with the holder named, and the GUI's own session holds it while open."""
from __future__ import annotations

import os

import pytest

from station.gui.controller import Controller
from station.recording.lock import FolderLock, FolderLocked, holder
from station.planning.request import PlanRequest
from tests.gui.helpers import wait_idle


def test_the_wizard_session_takes_the_folder_lock(qtbot, settings, tmp_path):
    c = Controller(simulate=True, settings=settings)
    errors, opened = [], []
    try:
        with FolderLock(tmp_path / "busy"):
            c.open_session(robot="agebot-sm", method="sm-distance-tilt", out_dir=tmp_path / "busy",
                           request=PlanRequest(), on_done=opened.append, on_error=errors.append)
            wait_idle(qtbot, c)
        assert not opened and len(errors) == 1 and isinstance(errors[0], FolderLocked)
        assert f"pid {os.getpid()} on " in str(errors[0])
        c.open_session(robot="agebot-sm", method="sm-distance-tilt", out_dir=tmp_path / "free",
                       request=PlanRequest(), on_done=opened.append, on_error=errors.append)
        wait_idle(qtbot, c)
        assert opened and len(errors) == 1
        assert holder(tmp_path / "free")["pid"] == os.getpid()
        with pytest.raises(FolderLocked):
            FolderLock(tmp_path / "free").acquire()
    finally:
        c.shutdown()
    assert holder(tmp_path / "free") is None
