"""The Setup page's robot and method choice: the robots listed, the method a robot kind
starts with, the words under the Method box, and "Plan in rounds" where it applies
(:class:`RobotMethodChoice`, a part of :class:`station.gui.pages.setup.SetupPage`)."""
from __future__ import annotations

import time
from pathlib import Path

from calibration.methods import METHODS
from calibration.robots import get_robot
from drivers.sim.serial_robot import is_robot_file
from station.fitting.start_values import ROUND_METHODS
from station.gui.pages.base import error_text
from station.planning.request import SESSION_METHODS

# the method a new session starts with (the README's): distance + tilt leaves none of
# the arm's parameters uncalibrated; the wrist's full orientation
DEFAULT_METHOD = {"serial": "sm-distance-tilt", "parallel-wrist": "pm-fk"}
METHOD_TEXT = {
    "sm-distance-tilt": "distance to a base origin you choose + tilt of the last link "
                        "(report 7.5): every parameter identifiable",
    "sm-distance": "distance to a reference point (report 7.2)",
    "pm-fk": "wrist orientation from the inclinometer, forward kinematics (report 10.2)",
    "pm-ik": "wrist orientation from the inclinometer, inverse kinematics (report 10.1)",
    "pm-tilt": "wrist roll and pitch only (10.2 with a physical inclinometer)",
}


ROBOT_FILES = Path(__file__).resolve().parents[3] / "fixtures" / "robots"


def robot_model(robot: str):
    """The model of a robot choice: a built-in name or a robot file's path."""
    if is_robot_file(robot):
        from drivers.robot_file import load_robot_file

        return get_robot(load_robot_file(robot))
    return get_robot(robot)


def draw_truth_file(robot_file: str, folder: Path, seed: int) -> Path:
    """A simulated arm of ``robot_file`` that is not its nominal, saved as
    ``folder/sim-truth.json``: what ``app.py truth draw`` writes
    (:func:`station.simulation.truth_cli.draw_truth_file`)."""
    from station.simulation.truth_cli import draw_truth_file as draw

    folder.mkdir(parents=True, exist_ok=True)
    return draw(robot_file, folder / "sim-truth.json", seed)


ROUNDS_TEXT = "Plan in rounds from the measured poses, and watch every move (recommended)"


def sessions_root() -> Path:
    """Where the wizard proposes session folders (made on the first Connect)."""
    return Path.home() / "calstation-sessions"


def default_folder() -> str:
    return str(sessions_root() / time.strftime("%Y%m%d-%H%M%S"))



class RobotMethodChoice:
    """The robot and method boxes of the Setup page (``self.robot``, ``self.method``,
    ``self.method_text``, ``self.rounds``, ``self.truth_row`` are its widgets)."""

    @property
    def robot_key(self) -> str:
        return self.robot.currentData()

    @property
    def method_name(self) -> str:
        return self.method.currentData()

    def set_choice(self, robot: str, method: str) -> None:
        """Choose ``robot`` (a built-in name or a robot file's path) and ``method``."""
        if is_robot_file(robot):
            robot = self.add_robot_file(robot)
        self.robot.setCurrentIndex(self.robot.findData(robot))
        if method:
            self.method.setCurrentIndex(self.method.findData(method))

    def add_robot_file(self, path: str) -> str:
        """List the robot file ``path`` (once); its key (the absolute path)."""
        key = str(Path(path).expanduser().resolve())
        if self.robot.findData(key) < 0:
            self.robot.addItem(f"robot file: {Path(path).name}", key)
        return key

    def robot_file_of(self, source: dict) -> str | None:
        """The listed robot file whose text is ``source`` (a trace's ``robot_file``)."""
        from drivers.robot_file import load_robot_file

        for i in range(self.robot.count()):
            key = self.robot.itemData(i)
            if is_robot_file(key):
                try:
                    if load_robot_file(key).source["sha256"] == source.get("sha256"):
                        return key
                except Exception:  # noqa: BLE001 - a listed file that went bad: not it
                    continue
        return None

    @property
    def robot_file(self) -> bool:
        return bool(self.robot_key) and is_robot_file(self.robot_key)

    def _robot_changed(self, *_):
        self.method.clear()
        self._robot_error = None
        try:
            kind = robot_model(self.robot_key).kind
        except Exception as e:  # noqa: BLE001 - said below
            self._robot_error = f"The robot file cannot be read: {error_text(e)}"
            kind = None
        for m in SESSION_METHODS:
            if METHODS[m].kind == kind:
                self.method.addItem(f"{m} (report {METHODS[m].section})", m)
        default = self.method.findData(DEFAULT_METHOD.get(kind, ""))
        if default >= 0:
            self.method.setCurrentIndex(default)
        self.truth_row.setEnabled(self.robot_file)
        self._method_changed()
        self.update_missing()

    def _method_changed(self, *_):
        text = METHOD_TEXT.get(self.method_name or "", "")
        if self.robot_file and self.method_name == "sm-distance-tilt":
            text = ("distance to a base origin you choose + the tool inclinometer's roll and "
                    "pitch (report 7.5); which of the robot file's parameters the measurements "
                    "determine is decided by the identifiability analysis (the Plan page "
                    "counts them, the Calibrate page lists them)")
        elif self.robot_file and self.method_name == "sm-distance":
            text += ("; the base frame's orientation and the first joint's zero are not seen "
                     "(the Calibrate page lists what is calibrated)")
        self.method_text.setText(text)
        if hasattr(self, "rounds"):      # the arm's rounds: AGEBOT's distance methods
            self._show_rounds()

    def _show_rounds(self) -> None:
        """"Plan in rounds" where it applies (AGEBOT's arm, distance methods), ticked as
        the operator left it; elsewhere the box unticked and hidden, and a line saying how
        the poses are planned (a greyed box that said "in rounds" unticked contradicted
        what happened)."""
        applies = self.robot_key == "agebot-sm" and self.method_name in ROUND_METHODS
        if applies:
            self.rounds.setText(ROUNDS_TEXT)
            self.rounds.setChecked(self._rounds_wanted)
        else:
            self.rounds.blockSignals(True)
            self.rounds.setChecked(False)
            self.rounds.blockSignals(False)
            self.rounds_note.setText(
                "Poses planned in rounds of the wrist's own: a scout round near home, then "
                "wider boxes" if self.robot_key == "agebot-pm" else
                "Poses planned at once (one shot) from the nominal inside the joint limits"
                if self.robot_file else "Poses planned at once")
        self.rounds.setEnabled(applies and not self.locked)
        self.rounds.setVisible(applies)
        self.rounds_note.setVisible(not applies)

