"""A URDF robot's parameters as people read them (issue 42, item 4): rotations in
degrees, never "mm"; the ratio held at 1 dimensionless; the points on the tool in mm;
the same in the console's table, the wizard's and the report's."""
from __future__ import annotations

import re

import app as app_module
from station.fitting.batch import calibrate_trace
from station.outputs.fit_summary import format_table
from station.outputs.report import write_report
from tests.station.urdf_helpers import import_args, tracker_case

EXPECT = {"base_x": "mm", "base_rx": "\u00b0", "base_roll": "\u00b0", "q2_off": "\u00b0",
          "k2": "1", "j2_x": "mm", "j2_ry": "\u00b0", "marker1_x": "mm"}


def test_a_urdf_robot_s_table_is_in_mm_and_degrees(tmp_path, capsys, qtbot):
    tracker_case(tmp_path, seed=3)
    assert app_module.main(import_args(tmp_path)) == 0
    capsys.readouterr()
    outcome = calibrate_trace(str(tmp_path / "t.jsonl"))
    table = format_table(outcome)
    for name, unit in EXPECT.items():
        row = next(ln for ln in table.splitlines() if ln.startswith(name + " "))
        assert row.split()[1] == unit, row
    # the report's parameter table
    html = write_report(tmp_path / "r.html", outcome).read_text(encoding="utf-8")
    for name, unit in EXPECT.items():
        m = re.search(rf'<td class="name">{name}</td>\s*<td[^>]*>([^<]*)</td>', html)
        assert m and m.group(1).strip() in (unit, "" if unit == "1" else unit), \
            (name, m and m.group(1))
    # the wizard's
    from station.gui.results import CalibrationView

    view = CalibrationView()
    qtbot.addWidget(view)
    view.show_outcome(outcome)
    t = view.params
    rows = {t.item(r, 0).text(): t.item(r, 1).text() for r in range(t.rowCount())
            if t.item(r, 0) is not None and t.item(r, 1) is not None}
    for name, unit in EXPECT.items():
        assert rows[name] in (unit, "" if unit == "1" else unit), (name, rows[name])
