"""The Setup page's robot and method choice: the robots listed, the method a robot kind
starts with, the words under the Method box, and "Plan in rounds" where it applies
(:class:`RobotMethodChoice`, a part of :class:`station.gui.pages.setup.SetupPage`); a
simulated robot drawn into the session folder (:meth:`RobotMethodChoice.draw_truth`).
A URDF robot's links and instrument: :mod:`station.gui.pages.setup_urdf`."""
from __future__ import annotations

import time
from pathlib import Path

from calibration.methods import METHODS
from calibration.robots import get_robot
from drivers.robot_file import split_urdf_ref, urdf_ref
from drivers.sim.serial_robot import is_robot_file
from station.fitting.start_values import ROUND_METHODS
from station.gui.pages.base import error_text
from station.gui.pages.setup_urdf import URDF_METHODS, UrdfChoice, is_urdf
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
    "sm-markers": "points on the tool (markers) measured by the motion capture in its own "
                  "frame (report 7.1): no reference; the instrument's frame and where the "
                  "markers sit on the tool are calibrated with the robot, first estimated "
                  "from a scout round near home",
}


ROBOT_FILES = Path(__file__).resolve().parents[3] / "fixtures" / "robots"


def robot_model(robot: str):
    """The model of a robot choice: a built-in name or a robot file's path."""
    if is_robot_file(robot):
        from drivers.robot_file import load_robot_file

        return get_robot(load_robot_file(robot))
    return get_robot(robot)


def draw_truth_file(robot_file: str, folder: Path, seed: int) -> Path:
    """A simulated arm of ``robot_file`` (a URDF robot: its chain, with a motion-capture
    room and markers on the tool) that is not its nominal, saved as
    ``folder/sim-truth.json`` (a URDF robot's true URDF beside it): what ``app.py truth
    draw`` writes (:func:`station.simulation.truth_cli.draw_truth_file`). The folders it
    made are removed again where nothing was written (no empty session folder left)."""
    from station.simulation.truth_cli import draw_truth_file as draw

    made = [p for p in (folder, *folder.parents) if not p.exists()]
    try:
        return draw(robot_file, folder / "sim-truth.json", seed)
    except BaseException:
        for p in made:           # the deepest first
            try:
                p.rmdir()        # only if empty
            except OSError:
                break
        raise


ROUNDS_TEXT = "Plan in rounds from the measured poses, and watch every move (recommended)"


def sessions_root() -> Path:
    """Where the wizard proposes session folders (made on the first Connect)."""
    return Path.home() / "calstation-sessions"


def default_folder() -> str:
    return str(sessions_root() / time.strftime("%Y%m%d-%H%M%S"))



class RobotMethodChoice(UrdfChoice):
    """The robot and method boxes of the Setup page (``self.robot``, ``self.method``,
    ``self.method_text``, ``self.rounds``, ``self.truth_row`` are its widgets)."""

    @property
    def robot_key(self) -> str:
        return self.robot.currentData()

    @property
    def method_name(self) -> str:
        return self.method.currentData()

    def set_choice(self, robot: str, method: str) -> None:
        """Choose ``robot`` (a built-in name, a robot file's path or a URDF robot's
        :func:`~drivers.robot_file.urdf_ref`) and ``method``."""
        if is_robot_file(robot):
            robot = self.add_robot_file(robot)
        self.robot.setCurrentIndex(self.robot.findData(robot))
        if method:
            self.method.setCurrentIndex(self.method.findData(method))

    def add_robot_file(self, path: str) -> str:
        """List the robot file ``path`` (once); its key (the absolute path; a URDF
        robot's: :meth:`add_urdf`)."""
        if split_urdf_ref(path) is not None or is_urdf(path):
            return self.add_urdf(path)
        key = str(Path(path).expanduser().resolve())
        if self.robot.findData(key) < 0:
            self.robot.addItem(f"robot file: {Path(path).name}", key)
        return key

    def robot_file_of(self, source: dict) -> str | None:
        """The listed robot file whose text is ``source`` (a trace's ``robot_file``; a
        URDF robot's with the trace's chain)."""
        import hashlib

        from drivers.robot_file import load_robot_file

        for i in range(self.robot.count()):
            key = self.robot.itemData(i)
            ref = split_urdf_ref(key)
            if ref is not None or is_urdf(key):
                path = ref[0] if ref else key
                try:
                    text = Path(path).read_text(encoding="utf-8").removeprefix("\ufeff")
                except OSError:
                    continue
                if (hashlib.sha256(text.encode("utf-8")).hexdigest() == source.get("sha256")
                        and source.get("base_link") and source.get("tip_link")):
                    return urdf_ref(path, source["base_link"], source["tip_link"])
            elif is_robot_file(key):
                try:
                    if load_robot_file(key).source["sha256"] == source.get("sha256"):
                        return key
                except Exception:  # noqa: BLE001 - a listed file that went bad: not it
                    continue
        return None

    def draw_truth(self) -> None:
        """Draw a simulated robot of the chosen robot file (or URDF robot) into the
        session folder; nothing is made where it cannot be drawn (said in the list)."""
        folder = self.folder.text().strip()
        if not self.robot_file or not folder or self._robot_error:
            self.update_missing()
            return
        seed = self.controller.sim_seed if self.controller.sim_seed is not None \
            else int(time.time()) % 100000
        try:
            path = draw_truth_file(self.robot_key, Path(folder).expanduser(), seed)
        except Exception as e:  # noqa: BLE001 - said to the operator
            self._error = f"No truth drawn: {error_text(e)}"
            self.update_missing()
            return
        self._error = None
        self.truth.setText(str(path))

    @property
    def robot_file(self) -> bool:
        return bool(self.robot_key) and is_robot_file(self.robot_key)

    def _robot_changed(self, *_):
        self.method.blockSignals(True)
        self.method.clear()
        self.method.blockSignals(False)
        self._robot_error = None
        self._show_links()
        urdf = self.urdf_path is not None
        if urdf:            # the station's methods of a URDF robot, the markers first
            methods, default = URDF_METHODS, URDF_METHODS[0]
            if self._robot_error is None:
                try:
                    robot_model(self.robot_key)
                except Exception as e:  # noqa: BLE001 - said below
                    self._robot_error = (f"The chain cannot be calibrated: {error_text(e)}")
        else:
            try:
                kind = robot_model(self.robot_key).kind
            except Exception as e:  # noqa: BLE001 - said below
                self._robot_error = f"The robot file cannot be read: {error_text(e)}"
                kind = None
            # sm-markers: a URDF robot's (the station's motion capture)
            methods = [m for m in SESSION_METHODS if METHODS[m].kind == kind
                       and m != "sm-markers"]
            default = DEFAULT_METHOD.get(kind, "")
        for m in methods:
            self.method.addItem(f"{m} (report {METHODS[m].section.split(',')[0]})", m)
        default = self.method.findData(default)
        if default >= 0:
            self.method.setCurrentIndex(default)
        self.truth_row.setEnabled(self.robot_file)
        self._method_changed()
        self.update_missing()

    def _method_changed(self, *_):
        text = METHOD_TEXT.get(self.method_name or "", "")
        whose = "URDF robot's" if self.urdf_path else "robot file's"
        if self.robot_file and self.method_name == "sm-distance-tilt":
            text = ("distance to a base origin you choose + the tool inclinometer's roll and "
                    f"pitch (report 7.5); which of the {whose} parameters the measurements "
                    "determine is decided by the identifiability analysis (the Plan page "
                    "counts them, the Calibrate page lists them)")
        elif self.robot_file and self.method_name == "sm-distance":
            text += ("; the base frame's orientation and the first joint's zero are not seen "
                     "(the Calibrate page lists what is calibrated)")
        self.method_text.setText(text)
        if hasattr(self, "rounds"):      # the arm's rounds: AGEBOT's distance methods
            self._show_rounds()
        if hasattr(self, "missing"):     # a URDF robot's instrument is the method's
            self.update_missing()

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
                "Poses planned in rounds: a scout round near home (it places the instrument's "
                "frame and the markers), then 60 % of the joints' box, then all of it"
                if self.method_name == "sm-markers" else
                "Poses planned at once (one shot) from the nominal inside the joint limits"
                if self.robot_file else "Poses planned at once")
        self.rounds.setEnabled(applies and not self.locked)
        self.rounds.setVisible(applies)
        self.rounds_note.setVisible(not applies)

