"""The accuracy test's HTML page (docs/accuracy.md, "The page"), from a made-up test of a
calibrated URDF arm (no devices: :func:`tests.station.iso_helpers.made_up_test`): the
page's numbers are those ``app.py accuracy`` prints (and those computed from the
readings in memory), it is written again from the CSV and the parameter file, a CSV of
another calibration (or edited, or not one) is refused in one line, and the session's
report beside the parameter file links it once. The faults and the operator's Stop in
the cycles (:mod:`station.session.iso_run`), on a stand-in rig."""
from __future__ import annotations

import html
import re

import numpy as np
import pytest

from calibration import iso9283
from drivers.errors import DeviceError
from station.outputs.iso9283 import PROGRAMS, attained, csv_text, table
from station.session import iso_run
from tests.station.iso_helpers import calibrate, made_up_test
from tests.station.cli_helpers import run, refused

CYCLES = 4


@pytest.fixture(scope="module")
def tested(tmp_path_factory):
    """``(folder, plan, readings)``: the arm calibrated, its made-up test written as
    ``accuracy.csv`` beside ``p.json``."""
    folder = calibrate(tmp_path_factory.mktemp("page"))
    plan, readings = made_up_test(folder, CYCLES)
    (folder / "accuracy.csv").write_text(csv_text(plan.tm, plan.cube, readings, plan.names))
    return folder, plan, readings


def _in_memory(plan, readings) -> list[str]:
    """The standard's table from the readings themselves (not the CSV)."""
    res = {}
    for prog in PROGRAMS:
        pos, ang, cmd = attained(plan.tm, plan.cube, readings[prog].points)
        rows = []
        for k, name in enumerate(iso9283.POINTS):
            ok = np.isfinite(pos[:, k]).all(axis=1)
            rows.append(iso9283.pose_result(name, pos[ok, k], cmd[k, :3, 3],
                                            None if ang is None else ang[ok, k]))
        res[prog] = rows
    return table(res)


def _cells(page: str, table_class: str) -> list[list[str]]:
    body = re.search(rf'<table class="{table_class}">.*?<tbody>(.*?)</tbody>', page, re.S)[1]
    return [[html.unescape(c) for c in re.findall(r"<td[^>]*>(.*?)</td>", row)]
            for row in re.findall(r"<tr[^>]*>(.*?)</tr>", body, re.S)]


def test_the_page_says_what_the_command_prints(tested, tmp_path, capsys):
    folder, plan, readings = tested
    page = tmp_path / "acc.html"
    rc, out, err = run(capsys, "accuracy", "--params", folder / "p.json", "--csv",
                       folder / "accuracy.csv", "--report", page)
    assert rc == 0, err
    printed = [ln for ln in out.splitlines() if re.match(r"(P\d|mean|pose) ", ln)]
    # the printed table is the readings' own (the CSV keeps them to the nm and 1e-6 deg)
    assert printed == _in_memory(plan, readings)
    text = page.read_text()
    assert "\n".join(printed) in html.unescape(text)            # "as printed" on the page
    rows = {r[0]: r for r in _cells(text, "position")}
    for line in printed[1:6]:
        name, apb, apa, rpb, rpa = line.split()
        assert rows[name][2:4] == [apb, apa] and rows[name][5:7] == [rpb, rpa], rows[name]
        assert rows[name][1] == (f"{CYCLES - 1}, {CYCLES}" if name == "P3" else
                                 f"{CYCLES}, {CYCLES}")     # the unseen point left out
    mean = printed[6].split()
    assert rows["mean"][2:4] == mean[1:3] and rows["mean"][5:7] == mean[3:5]
    # the summary's factor and the orientation as printed
    factor = re.search(r"([\d.]+) times closer", out)[1]
    assert rows["RMS"][4] == factor and f"{factor} times closer" in text
    orient = {r[0]: r for r in _cells(text, "orientation")}
    for line in printed[7:]:
        if line.startswith("pose"):
            continue
        values = line.split()
        assert orient[values[0]][1:] == values[1:], (orient[values[0]], values)
    # the cube, the predicted error, what is not covered, two figures
    edge = f"edge {plan.cube.size * 1e3:.1f} mm"
    assert edge in text and "predicted error of the tool at the compensated poses" in text
    assert "What this test does not cover" in text and "path accuracy" in text
    assert text.count("data:image/svg+xml;base64,") == 2
    assert "nominal P3: 1" in text          # the cycle left out, said


def test_a_csv_that_is_not_the_parameter_file_s_is_refused_in_one_line(tested, tmp_path,
                                                                       capsys):
    folder, plan, readings = tested
    other = calibrate(tmp_path / "other", draw=11)            # the same arm, another trace
    csv = folder / "accuracy.csv"
    page = ["--report", tmp_path / "x.html"]
    refused(capsys, ["accuracy", "--params", other / "p.json", "--csv", csv, *page],
            f"{csv}:", "not measured with p.json's calibration")
    lines = csv.read_text().splitlines()
    head = lines[0].split(",")
    j = head.index("joint_3_cmd")
    edited = [lines[0]] + [",".join(c if i != j or not ln.startswith("compensated") else
                                    f"{float(c) + 1e-4:.9f}"
                                    for i, c in enumerate(ln.split(",")))
                           for ln in lines[1:]]
    (tmp_path / "e.csv").write_text("\n".join(edited) + "\n")
    refused(capsys, ["accuracy", "--params", folder / "p.json", "--csv", tmp_path / "e.csv",
                     *page], "e.csv:", "compensated program's")
    (tmp_path / "short.csv").write_text("\n".join(lines[:12]) + "\n")
    refused(capsys, ["accuracy", "--params", folder / "p.json", "--csv",
                     tmp_path / "short.csv", *page], "short.csv:", "cycle")
    refused(capsys, ["accuracy", "--params", folder / "p.json", "--csv", folder / "t.jsonl",
                     *page], "t.jsonl:", "not an accuracy CSV")
    refused(capsys, ["accuracy", "--params", folder / "p.json", "--csv", csv, "--report",
                     folder / "p.json"], "it is the input")
    assert not (tmp_path / "x.html").exists()


def test_the_session_s_report_links_the_page_once(tested, tmp_path, capsys):
    folder, plan, readings = tested
    checksum = plan.doc["checksum"]
    report = folder / "report.html"
    report.write_text(f"<html><body><main><p>{checksum}</p><footer>made</footer></main>"
                      "</body></html>\n")
    for _ in range(2):
        rc, out, err = run(capsys, "accuracy", "--params", folder / "p.json", "--csv",
                           folder / "accuracy.csv")
        assert rc == 0 and f"linked from {report}" in out, err
    text = report.read_text()
    assert text.count('<section id="accuracy">') == 1 and 'href="accuracy.html"' in text
    assert text.index('<section id="accuracy">') < text.index("<footer>")
    assert (folder / "accuracy.html").is_file()
    # the page cannot be written over the report; another file's report is not touched
    refused(capsys, ["accuracy", "--params", folder / "p.json", "--csv",
                     folder / "accuracy.csv", "--report", report], "it is the input")
    report.write_text("<html><footer>another</footer></html>\n")
    rc, out, _err = run(capsys, "accuracy", "--params", folder / "p.json", "--csv",
                        folder / "accuracy.csv")
    assert rc == 0 and "is not the report of p.json" in out
    assert report.read_text() == "<html><footer>another</footer></html>\n"
    report.unlink()


# -- the cycles: faults and Stop ------------------------------------------------------------
class _Rig:
    """A stand-in rig: records the moves, fails the moves listed in ``fail`` (by their
    number, 0-based) with a DeviceError."""

    def __init__(self, fail=()):
        self.moves, self.fail, self.recovered = [], set(fail), 0

    def move_to(self, q):
        n = len(self.moves)
        self.moves.append(int(round(float(q[0]))))
        if n in self.fail:
            raise DeviceError("no answer", device="canopen node 2")

    def snapshot(self):
        return type("S", (), {"mean": {"m1_x": 1.0, "m1_y": 2.0, "m1_z": 3.0,
                                       **{f"qm{i + 1}": 0.0 for i in range(2)}},
                              "t_start": "t"})()

    def recover(self):
        self.recovered += 1


def _program():
    from types import SimpleNamespace

    q = np.array([[k, 0.0] for k in range(5)], dtype=float)      # P(k+1): joint 1 = k
    env = SimpleNamespace(envelope=None)
    return q, env


def test_a_fault_is_retried_from_the_pose_before_skipped_or_stops_the_test(monkeypatch):
    monkeypatch.setattr(iso_run, "limit_violation", lambda q, env: None)
    monkeypatch.setattr(iso_run, "backoff", lambda attempt: 0.0)
    q, config = _program()
    asked = []

    def policy(answer):
        def ask(where, error, attempt):
            asked.append((str(where), attempt))
            return answer
        return ask

    # the 3rd move (P5 of cycle 1) fails once: P1 again, then P5 (the same direction)
    rig = _Rig(fail={2})
    r = iso_run.run_program(rig, config, q, 2, 1, name="nominal", fault_policy=policy("retry"))
    assert rig.moves[:5] == [1, 0, 4, 0, 4] and rig.recovered == 1
    assert np.isfinite(r.points).all()
    assert asked == [("P5 of cycle 1 of 2, the nominal program", 0)]
    # skipped: the rest of cycle 1 left out, cycle 2 from P2 again
    rig = _Rig(fail={3})
    r = iso_run.run_program(rig, config, q, 2, 1, name="nominal", fault_policy=policy("skip"))
    seen = np.isfinite(r.points[:, :, 0, 0])
    assert seen[0].tolist() == [True, False, False, False, True]    # P1, P5 before P4
    assert seen[1].all() and rig.moves[4:6] == [1, 0]
    # aborted, or no policy (app.py accuracy): the test stops, one line
    with pytest.raises(iso_run.TestStopped, match="nothing written"):
        iso_run.run_program(_Rig(fail={3}), config, q, 2, 1, name="nominal",
                            fault_policy=policy("abort"))
    with pytest.raises(DeviceError):
        iso_run.run_program(_Rig(fail={3}), config, q, 2, 1, name="nominal")
    # the operator's Stop: before the next move
    rig = _Rig()
    with pytest.raises(iso_run.TestStopped, match="stopped before P4 of cycle 1"):
        iso_run.run_program(rig, config, q, 2, 1, name="nominal",
                            stop=lambda: len(rig.moves) >= 3)
    assert len(rig.moves) == 3
