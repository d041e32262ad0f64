"""The Setup page's URDF robot (:class:`UrdfChoice`, a part of
:class:`station.gui.pages.setup.SetupPage`): the links of its file in two boxes, every
link offered (the root link and the deepest leaf of the longest chain by default, or the
links the robot came with: ``--base-link``/``--tip-link``), a chain that cannot be
calibrated said in one line, and the instrument the station has for the chosen method
(a motion capture with its markers, or the draw-wire and the tool's inclinometer).

A URDF robot is named as the station names it everywhere, its file and chain
(:func:`drivers.robot_file.urdf_ref`): that is the robot box's data for it.
"""
from __future__ import annotations

import io
import logging
import os
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

from PySide6.QtWidgets import QComboBox, QHBoxLayout, QLabel, QWidget

from drivers.robot_file import split_urdf_ref, urdf_ref
from drivers.urdf_file import MOVABLE, is_urdf
from station.gui.pages.base import error_text
from station.gui.widgets import BAD_COLOR, note

#: the methods a URDF robot is measured with at the station, the first the default
URDF_METHODS = ("sm-markers", "sm-distance", "sm-distance-tilt")
#: the Robot file... dialog's filter: robot files and URDFs
URDF_FILTER = ("Robot file or URDF (*.toml *.urdf *.xml);;Robot file (*.toml);;"
               "URDF (*.urdf *.xml);;All files (*)")


@dataclass(frozen=True)
class UrdfTree:
    """A URDF's links (in the file's order), each link's parent ``(link, joint type)``,
    the root link and the deepest leaf of the longest chain (most movable joints)."""

    links: tuple[str, ...]
    parent: dict
    root: str
    tip: str

    def chain_problem(self, base: str, tip: str) -> str | None:
        """Why the chain ``base`` to ``tip`` cannot be calibrated (one line), else None."""
        for what, link in (("base link", base), ("tip link", tip)):
            if link not in self.links:
                return f"the {what} {link} is not a link of the URDF"
        movable, link = 0, tip
        while link != base:
            if link not in self.parent:
                return (f"the tip link {tip} is not below the base link {base} in the URDF's "
                        "tree: choose a tip link on a chain that starts at the base link")
            link, kind = self.parent[link]
            movable += kind in MOVABLE
        if not movable:
            return (f"no movable joint between {base} and {tip}: choose a tip link further "
                    "down the chain")
        return None


_TREES: dict = {}


def urdf_tree(path: str) -> UrdfTree:
    """The :class:`UrdfTree` of the URDF file ``path``, read with yourdfpy as the station
    reads it (:mod:`drivers.urdf_file`; checked first, errors in one line naming the
    file); cached while the file is unchanged."""
    from calibration.errors import ConfigError
    from drivers.config_reader import read_text_file
    from drivers.urdf_checks import check_urdf

    st = os.stat(path)
    key = (str(path), st.st_mtime_ns, st.st_size)
    if key in _TREES:
        return _TREES[key]
    text = read_text_file(path, "the URDF")
    try:
        ET.fromstring(text)
    except ET.ParseError as e:
        line, col = e.position
        raise ConfigError(f"not valid XML at line {line}, column {col + 1}", source=path) \
            from None
    check_urdf(text, path)
    import yourdfpy

    log = logging.getLogger("yourdfpy")
    level, log.level = log.level, logging.CRITICAL
    try:
        urdf = yourdfpy.URDF.load(io.BytesIO(text.encode("utf-8")), load_meshes=False,
                                  build_scene_graph=False, load_collision_meshes=False)
    except Exception as e:  # noqa: BLE001 - yourdfpy raises what its XML walk meets
        raise ConfigError(f"not a URDF yourdfpy can read: {type(e).__name__}: {e}",
                          source=path) from None
    finally:
        log.level = level
    links = tuple(lk.name for lk in urdf.robot.links)
    parent = {j.child: (j.parent, j.type) for j in urdf.robot.joints}
    roots = [lk for lk in links if lk not in parent]
    if not roots:
        raise ConfigError("no root link (every link is a joint's child)", source=path)
    parents = {p for p, _ in parent.values()}

    def depth(link):
        movable = joints = 0
        while link in parent:
            link, kind = parent[link]
            movable, joints = movable + (kind in MOVABLE), joints + 1
        return movable, joints

    leaves = [lk for lk in links if lk not in parents and lk in parent] or [roots[0]]
    tree = UrdfTree(links, parent, roots[0], max(leaves, key=depth))
    _TREES[key] = tree
    return tree


def instrument_text(config, method: str | None, simulate: bool) -> tuple[str, str | None]:
    """``(what the station measures the chosen method with, what is missing or None)``
    from the station ``config`` (None: not known yet)."""
    if config is None:
        return ("the simulated station: a motion capture of the truth file's room (its "
                "markers), the draw-wire and the tool's inclinometer" if simulate else
                "the station config's (choose it)"), None
    mocap, dw, incl = config.mocap, config.drawwire, config.inclinometer
    where = "simulated " if simulate else ""
    if method == "sm-markers":
        if mocap is None:
            return ("no motion capture", "sm-markers measures points on the tool with a "
                    "motion capture, and the station config has none ([mocap]): choose "
                    "another method or station config")
        return (f"the {where}motion capture (QTM), {len(mocap.labels)} markers on the tool: "
                f"{', '.join(mocap.labels)}; a marker it does not see at a pose leaves that "
                "pose with fewer points"), None
    parts = []
    if dw is not None:
        parts.append(f"the {where}draw-wire (distance)")
    if incl is not None and method == "sm-distance-tilt":
        parts.append("the tool's inclinometer (" + ", ".join(incl.axes) + ")")
    missing = None
    if dw is None:
        missing = (f"{method} measures distances, and the station config has no draw-wire "
                   "([drawwire]): choose sm-markers or another station config")
    elif method == "sm-distance-tilt" and incl is None:
        missing = ("sm-distance-tilt measures the tool's tilt, and the station config has no "
                   "inclinometer ([inclinometer])")
    return (" and ".join(parts) or "nothing it can measure with"), missing


class UrdfChoice:
    """The link boxes and the instrument line of the Setup page (its ``robot`` box and
    ``method`` box; ``self._robot_error`` and ``self._station_error`` said in its list of
    what is missing)."""

    def _build_urdf_rows(self, form) -> None:
        self.base_link, self.tip_link = QComboBox(), QComboBox()
        for box, tip in ((self.base_link, "the link the chain to calibrate starts at (the "
                          "robot's base, fixed in the room)"),
                         (self.tip_link, "the link the chain ends at (the tool flange that "
                          "carries the markers)")):
            box.setToolTip(tip)
            box.setSizeAdjustPolicy(QComboBox.SizeAdjustPolicy.AdjustToContents)
            box.currentIndexChanged.connect(self._links_changed)
        self.links_row = QWidget()
        lay = QHBoxLayout(self.links_row)
        lay.setContentsMargins(0, 0, 0, 0)
        for text, box in (("&Base link:", self.base_link), ("T&ip link:", self.tip_link)):
            label = QLabel(text)
            label.setBuddy(box)
            lay.addWidget(label)
            lay.addWidget(box)
        lay.addStretch(1)
        self.instrument = note("")
        self.instrument.setObjectName("instrument")
        form.addRow("Chain:", self.links_row)
        form.addRow("Instrument:", self.instrument)
        self._urdf_form = form
        self._station_error: str | None = None
        self._station_key = None

    @property
    def urdf_path(self) -> str | None:
        """The chosen robot's URDF file, else None."""
        key = self.robot_key or ""
        ref = split_urdf_ref(key)
        if ref is not None:
            return ref[0]
        return key if key and is_urdf(key) else None

    def add_urdf(self, robot: str) -> str:
        """List the URDF robot ``robot`` (a file, or a file with its chain: its
        :func:`urdf_ref`) once a file, its links as given, else the default ones; its key."""
        ref = split_urdf_ref(robot)
        path, base, tip = ref if ref is not None else (robot, None, None)
        path = str(Path(path).expanduser().resolve())
        if base is None:
            try:
                tree = urdf_tree(path)
                base, tip = tree.root, tree.tip
            except Exception:  # noqa: BLE001 - said when it is chosen (_show_links)
                pass
        key = urdf_ref(path, base, tip) if base and tip else path
        for i in range(self.robot.count()):
            data = self.robot.itemData(i)
            there = split_urdf_ref(data or "")
            if (there[0] if there else data) == path:
                self.robot.setItemData(i, key)
                return key
        self.robot.addItem(f"URDF: {Path(path).name}", key)
        return key

    def _show_links(self) -> None:
        """The link boxes of the chosen URDF (hidden for another robot); a URDF that
        cannot be read or a chain that cannot be calibrated: ``_robot_error``."""
        path = self.urdf_path
        shown = path is not None
        for w in (self.links_row, self.instrument):
            self._urdf_form.setRowVisible(w, shown)
        if not shown:
            return
        ref = split_urdf_ref(self.robot_key)
        base, tip = (ref[1], ref[2]) if ref else (None, None)
        try:
            tree = urdf_tree(path)
        except Exception as e:  # noqa: BLE001 - said on the page
            self._robot_error = f"The URDF cannot be read: {error_text(e)}"
            tree = None
        for box, link in ((self.base_link, base), (self.tip_link, tip)):
            box.blockSignals(True)
            box.clear()
            for name in (tree.links if tree else ()):
                box.addItem(name, name)
            box.setCurrentIndex(box.findData(link) if link else -1)
            box.blockSignals(False)
        if tree is not None and base and tip:
            problem = tree.chain_problem(base, tip)
            if problem:
                self._robot_error = (f"The chain {base} to {tip} cannot be calibrated: "
                                     f"{problem}.")

    def _links_changed(self, *_) -> None:
        path, base, tip = self.urdf_path, self.base_link.currentData(), \
            self.tip_link.currentData()
        if path is None or not base or not tip:
            return
        self.robot.setItemData(self.robot.currentIndex(), urdf_ref(path, base, tip))
        self._robot_changed()

    # -- the instrument ---------------------------------------------------------------
    def _station_config(self):
        """The station config the session will have (simulated: the simulator's, with
        the truth file's room), None where it is not known yet; errors raised."""
        c = self.controller
        config = self.config.text().strip() or None
        if c.simulate:
            truth = self.truth.text().strip()
            if not truth:
                return None
            from drivers.sim.station_files import load_sim_config, truth_of

            truth_of(self.robot_key, truth)           # of this robot and chain, or said
            return load_sim_config(self.robot_key, config, truth)
        if not config:
            return None
        from drivers.config import load_station_config

        return load_station_config(config)

    def update_instrument(self) -> None:
        """The instrument line of a URDF robot for the chosen method, and
        ``_station_error`` (what keeps it from measuring; a truth file of another
        robot); computed again when the robot, method, truth or config changed."""
        if self.urdf_path is None or self._robot_error:
            self._station_error, self._station_key = None, None
            self.instrument.setText("\u2013 (a chain to calibrate first)")
            self.instrument.setStyleSheet("")
            return
        key = (self.robot_key, self.method_name, self.truth.text().strip(),
               self.config.text().strip())
        if key == self._station_key:
            return
        self._station_key = key
        self._station_error = None
        try:
            config = self._station_config()
        except Exception as e:  # noqa: BLE001 - said on the page
            if self.controller.simulate:
                self._station_error = (f"The truth file cannot be used for this robot: "
                                       f"{error_text(e)} (choose this robot's truth file, "
                                       "or press Draw one)")
            else:
                self._station_error = f"The station config cannot be used: {error_text(e)}"
            self.instrument.setText("\u2013")
            self.instrument.setStyleSheet(f"color: {BAD_COLOR};")
            return
        text, missing = instrument_text(config, self.method_name, self.controller.simulate)
        self.instrument.setText(text)
        self.instrument.setStyleSheet(f"color: {BAD_COLOR};" if missing else "")
        self._station_error = missing
