"""Page 3, Plan: the IK-planned poses in a table and in the workspace, their
count against eq. 60's minimum; regenerate (count, held out, seed) and edit
(remove poses, switch fit / held out)."""
from __future__ import annotations

import dataclasses
import math

from PySide6.QtCore import Qt
from PySide6.QtGui import QColor
from PySide6.QtWidgets import (QAbstractItemView, QComboBox, QHBoxLayout, QHeaderView,
                               QLabel, QPushButton, QSpinBox, QSplitter, QTableWidget,
                               QTableWidgetItem)

from station.gui.pages.base import Page
from station.planning.pose_design import design_text
from station.gui.plots import WorkspacePlot
from station.gui.widgets import BAD_COLOR, OK_COLOR, fixed, note, target_coords
from station.planning.wrist_plan import PM_SCOUT_COUNT


class PlanPage(Page):
    title = "Plan"
    subtitle = ("The poses the robot will be measured in, planned with its inverse kinematics "
                "inside the joint limits and ordered for short travel. Held-out poses are "
                "measured but never fitted: they check the result.")

    def __init__(self, controller, parent=None):
        super().__init__(controller, parent)
        bar = QHBoxLayout()
        self.count = QSpinBox()
        self.count.setRange(0, 500)
        self.count.setSpecialValueText("auto")
        self.validation = QSpinBox()
        self.validation.setRange(-1, 200)
        self.validation.setSpecialValueText("auto")
        self.seed = QSpinBox()
        self.seed.setRange(0, 1_000_000)
        self.design = QComboBox()
        self.design.addItem("optimal (D-optimal)", "optimal")
        self.design.addItem("random", "random")
        self.design.setToolTip("optimal: each round's poses chosen from ten times as many "
                               "candidates to tell the most about the parameters, given those "
                               "measured (docs/design.md); random: drawn in the box")
        for text, w in (("&Poses to fit:", self.count), ("Hel&d out:", self.validation),
                        ("S&eed:", self.seed), ("Desi&gn:", self.design)):
            lab = QLabel(text)
            lab.setBuddy(w)
            bar.addWidget(lab)
            bar.addWidget(w)
        self.regenerate_button = QPushButton("&Regenerate")
        self.regenerate_button.clicked.connect(self.regenerate)
        self.remove_button = QPushButton("Remo&ve selected")
        self.remove_button.clicked.connect(self.remove_selected)
        self.toggle_button = QPushButton("Fit \u2194 held &out")
        self.toggle_button.clicked.connect(self.toggle_selected)
        for b in (self.regenerate_button, self.remove_button, self.toggle_button):
            b.setAutoDefault(False)
            bar.addWidget(b)
        bar.addStretch(1)
        self.layout_.addLayout(bar)
        self.counts = note("")
        self.layout_.addWidget(self.counts)
        # the table over the plot, each the page's whole width: every column in sight
        # at 1366x768 without scrolling sideways (a robot file's 16 columns too)
        split = self.split = QSplitter(Qt.Orientation.Vertical)
        self.table = QTableWidget(0, 0)
        self.table.setSelectionBehavior(QAbstractItemView.SelectionBehavior.SelectRows)
        self.table.setEditTriggers(QAbstractItemView.EditTrigger.NoEditTriggers)
        self.table.verticalHeader().setVisible(False)
        self.table.setMinimumHeight(220)
        self.plot = WorkspacePlot()
        split.addWidget(self.table)
        split.addWidget(self.plot)
        self.plot.setMinimumHeight(380)
        split.setSizes([300, 420])
        self.layout_.addWidget(split, 1)
        self.status = note("")
        self.layout_.addWidget(self.status)
        controller.stateChanged.connect(self._state)
        controller.busyChanged.connect(self._busy)

    def initialize_page(self) -> None:
        s = self.session
        if s is None:
            return
        req = s.request
        self.count.setValue(req.count or 0)
        self.validation.setValue(-1 if req.validation is None else req.validation)
        self.seed.setValue(req.seed)
        self.design.setCurrentIndex(max(0, self.design.findData(req.design)))
        if not s.plan_poses:
            self.regenerate()
        else:
            self.show_plan()

    def _locked(self) -> bool:
        s = self.session
        return s is None or any(p.index in s.measured or p.index in s.skipped
                                for p in s.plan_poses)

    def regenerate(self) -> None:
        s = self.session
        if s is None:
            return
        if self._locked():
            self.status.setText("Poses of this plan are recorded already: it cannot be replaced "
                                "(start a new session in another folder for a new plan).")
            return
        s.request = dataclasses.replace(
            s.request, count=self.count.value() or None,
            validation=None if self.validation.value() < 0 else self.validation.value(),
            seed=self.seed.value(), design=self.design.currentData())
        self.status.setText("Planning\u2026")
        self.controller.run(lambda s: s.plan(), lambda _: self.show_plan(),
                            lambda e: self.show_error("Planning failed", e))

    def _selected(self) -> list[int]:
        return sorted({i.row() for i in self.table.selectedIndexes()})

    def remove_selected(self) -> None:
        self._edit(lambda poses, rows: [p for k, p in enumerate(poses) if k not in rows])

    def toggle_selected(self) -> None:
        def toggle(poses, rows):
            return [dataclasses.replace(p, use="validation" if p.use == "fit" else "fit")
                    if k in rows else p for k, p in enumerate(poses)]
        self._edit(toggle)

    def _edit(self, change) -> None:
        s = self.session
        rows = set(self._selected())
        if s is None or not rows or self._locked():
            return
        poses = change(list(s.plan_poses), rows)
        self.controller.run(lambda _s: self.controller.set_plan(poses),
                            lambda _: self.show_plan(),
                            lambda e: self.show_error("The plan was not changed", e))

    def show_plan(self) -> None:
        s = self.session
        if s is None:
            return
        poses = s.plan_poses
        n = s.robot.n_actuators
        u = self.controller.units
        names, sis = target_coords(s.robot)
        coords = tuple(f"{k} [{u.label(si)}]" for k, si in zip(names, sis))
        heads = ["#", "use", "round", "state"] + [f"qm{i + 1}" for i in range(n)] + list(coords)
        t = self.table
        t.setColumnCount(len(heads))
        t.setHorizontalHeaderLabels(heads)
        t.setRowCount(len(poses))
        markers = s.method == "sm-markers"      # a URDF robot's scout, middle, last rounds
        rounds = s.robot.name == "agebot-pm" or s.rounds is not None or markers
        for r, p in enumerate(poses):
            state = ("measured" if p.index in s.measured else
                     "skipped" if p.index in s.skipped else "to measure")
            tgt = [u.value(v, si) for v, si in zip(p.target, sis)]
            cells = [str(p.index), "held out" if p.use == "validation" else "fit",
                     ("scout" if p.round == 0 else f"round {p.round}") if rounds else "",
                     state] + [fixed(v, 3) for v in p.qm] + [fixed(v, 3) for v in tgt]
            for c, text in enumerate(cells):
                item = QTableWidgetItem(text)
                if c >= 4 or c == 0:
                    item.setTextAlignment(Qt.AlignmentFlag.AlignRight
                                          | Qt.AlignmentFlag.AlignVCenter)
                if c == 1 and p.use == "validation":
                    item.setForeground(QColor("#b35900"))
                t.setItem(r, c, item)
        t.horizontalHeader().setSectionResizeMode(QHeaderView.ResizeMode.ResizeToContents)
        t.setColumnHidden(2, not rounds)        # one shot: no rounds to tell apart
        ref = None
        if s.reference_qm is not None and s.method == "sm-distance-tilt":
            ref = [0.0, 0.0, 0.0]       # the targets are planned in the base-origin frame
        elif s.reference_qm is not None and s.robot.name == "agebot-sm":
            ref = s.robot.fk(s.reference_qm, s.nominal)[0]
        if s.serial:        # the tool's targets in the robot file's base frame, the arm
            self.plot.show_arm_plan(poses, s.robot, s.nominal, s.reference_qm, s.measured.keys(),
                                    from_qm=markers)
        else:
            self.plot.show_plan(poses, s.robot.name, s.measured.keys(), ref)
        n_fit = sum(p.use == "fit" for p in poses)
        n_val = len(poses) - n_fit
        need = s.minimum_count
        text = f"{n_fit} poses to fit + {n_val} held out; eq. 60 minimum {need}."
        if s.robot.name == "agebot-pm" and all(p.round == 0 for p in poses):
            want = (s.request.count or math.ceil(s.request.margin * need))
            text += (f" This is the scout round ({PM_SCOUT_COUNT} poses near home); after it "
                     "is measured the box grows round by round, each planned from the fit of "
                     f"the poses recorded so far, up to +-20 deg, for {want} fit poses in all.")
            ok = want >= need
        elif markers and all(p.round == 0 for p in poses):
            text += (f" This is the scout round ({len(poses)} poses near home): the motion "
                     "capture's frame and the markers on the tool are estimated from it, then "
                     "two rounds are planned from that estimate (60 % of the joints' box, then "
                     f"all of it) for {s.request.count or 2 * need} fit poses and the held-out "
                     "ones, every marker in the volume and facing the cameras.")
            ok = (s.request.count or 2 * need) >= need
        elif s.rounds is not None and all(p.round == 0 for p in poses):
            want, held = s.rounds.fit_total(), s.rounds.totals()[1]
            text += (f" This is the scout round ({len(poses)} poses a small step from the "
                     "reference); after it the arm is planned in rounds from their fit (30 % of "
                     f"the box, then all of it), for {want} fit poses + {held} held out in all.")
            ok = want >= need
        else:
            ok = n_fit >= need
        if not ok:
            text += " Fewer than the minimum: the result will be less certain (add poses)."
        if getattr(s, "last_design", None):
            text += " " + design_text(s.last_design, s.units).capitalize() + "."
        self.counts.setText(text)
        self.counts.setStyleSheet(f"color: {OK_COLOR if ok else BAD_COLOR};")
        locked = self._locked()
        for b in (self.regenerate_button, self.remove_button, self.toggle_button):
            b.setEnabled(not locked)
        self.status.setText("Recorded poses: this plan is fixed." if locked else "")
        self.completeChanged.emit()

    def is_complete(self) -> bool:
        s = self.session
        return bool(s is not None and s.plan_poses)

    def _state(self, state: str) -> None:
        if state == "planned" and self.isVisible():
            self.show_plan()

    def _busy(self, busy: bool) -> None:
        self.regenerate_button.setEnabled(not busy and not self._locked())

