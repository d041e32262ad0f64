"""Exact resume: a session killed after any line of its trace (or in the middle of
one) and run again ends with the trace and the result of the uninterrupted session.

The simulator runs with pose-keyed noise (``--pose-noise``): a reading at rest is a
function of the seed and the pose, so a pose read in the resumed run reads what it
read in the uninterrupted one, and a pose lost, repeated or read against a lost
draw-wire zero changes the result far beyond rounding. "Killed after line k" is the
uninterrupted run's first k lines (plus half of line k + 1 for a kill mid-line),
with the devices left as a crash leaves them: the robot back at its start and the
draw-wire zeroed there (a sensor that lost its zero). One real SIGKILL is in
tests/station/test_session.py.
"""
from __future__ import annotations

import dataclasses
import warnings
from pathlib import Path

import numpy as np
import pytest

from calibration.robots import get_robot
from drivers.rig import Rig
from drivers.sim.server import SimulatorProcess
from drivers.sim.truth import load_truth, save_truth
from station.planning.request import PlanRequest
from station.session.session import Session
from station.recording.trace import read_trace
from tests.simconfig import quick_config, set_keys
from tests.station.test_session import FIX, _session_config, referenced_folder

@pytest.fixture(autouse=True)
def _no_figures(monkeypatch):
    """The HTML report (matplotlib figures, ~90 % of a session's time here) is not what
    these tests compare: a one-line report stands in (tests/station/test_report.py)."""
    import station.outputs.report

    monkeypatch.setattr(station.outputs.report, "write_report",
                        lambda path, *a, **k: Path(path).write_text("report\n"))


CHANNELS = {"sm-distance-tilt": ("qm", "distance", "tilt"), "pm-fk": ("qm", "orientation")}


@dataclasses.dataclass
class Case:
    method: str
    config: object
    request: PlanRequest
    nominal: dict
    start_qm: list
    lines: list[bytes]
    records: dict          # plan index -> pose record of the uninterrupted run
    x: np.ndarray
    std: np.ndarray


def _truth(tmp_path: Path, robot: str) -> str:
    """The unseen robot (noise as the truth file gives it); pm-fk: sensor mounted square."""
    truth = load_truth(FIX / "truth" / f"{robot}-unseen.json")
    if robot == "agebot-pm":
        truth = dataclasses.replace(truth, inclinometer_mount=(0.0, 0.0))
    path = tmp_path / f"{robot}-truth.json"
    save_truth(truth, path)
    return str(path)


def _config(tmp_path: Path, robot: str) -> Path:
    """:func:`fast_config` with two samples a pose (shorter tests) and an SDO timeout of
    2 s: what is tested is the exact resume, and a simulator process starved on a loaded
    machine once missed the 0.5 s of the fixture while the drives were configured."""
    path = quick_config(tmp_path, robot, samples=2)
    path.write_text(set_keys(path.read_text(), "canopen", sdo_timeout=2.0))
    return path


def _uninterrupted(tmp_path, sim, cfg, method, request, nominal) -> Case:
    config = _session_config(sim, cfg)
    with sim.control() as ctl:
        start = ctl.call(state=True)["qm"]
    _as_after_a_crash(config, start)        # the start pose as a move leaves it
    # exact resume is about the trace: 10 poses are too few for a fit that passes the
    # fit-quality gate, and the poor fit is accepted in both runs alike
    with Session(config, method, tmp_path / "whole", request=request, nominal=nominal,
                 accept_poor_fit=True) as s:
        s.run()
    res = s.outcome.result
    trace = read_trace(s.trace_path)
    return Case(method, config, request, nominal, start, s.trace_path.read_bytes().splitlines(True),
                {p["plan_index"]: p for p in trace.poses}, res.x.copy(), res.std.copy())


def _as_after_a_crash(config, start_qm) -> None:
    """The robot back at its start and the draw-wire zeroed there (its zero lost)."""
    with Rig(config) as rig:
        rig.move_to(start_qm)
        if rig.drawwire is not None:
            rig.zero_drawwire()


def _resume_after(tmp_path, case: Case, k: int, partial: bool) -> tuple[dict, np.ndarray]:
    """Kill after line ``k`` (and half of line k + 1 with ``partial``), resume, finish."""
    out = tmp_path / f"kill-{k}{'-partial' if partial else ''}"
    out.mkdir()
    data = b"".join(case.lines[:k])
    if partial:
        data += case.lines[k][: len(case.lines[k]) // 2]
    (out / "trace.jsonl").write_bytes(data)
    _as_after_a_crash(case.config, case.start_qm)
    with Session(case.config, case.method, out, request=case.request, nominal=case.nominal,
                 accept_poor_fit=True) as s:
        s.run()
    with warnings.catch_warnings():
        warnings.simplefilter("error")       # the resumed trace has no truncated line left
        trace = read_trace(s.trace_path)
    return {p["plan_index"]: p for p in trace.poses}, s.outcome.result.x


def _check_same(case: Case, k: int, records: dict, x: np.ndarray) -> float:
    """The resumed run's poses are the uninterrupted run's, reading by reading, and so
    are its parameters; returns the largest parameter difference in std."""
    assert sorted(records) == sorted(case.records), f"kill after line {k}: other poses"
    for i, rec in records.items():
        for ch in CHANNELS[case.method]:
            np.testing.assert_allclose(rec[ch], case.records[i][ch], rtol=0, atol=1e-12,
                                       err_msg=f"kill after line {k}: pose {i} {ch}")
    np.testing.assert_allclose(x, case.x, rtol=1e-9, atol=1e-12, err_msg=f"kill after line {k}")
    ok = np.isfinite(case.std)              # the identifiable ones
    ratio = float(np.max(np.abs(x - case.x)[ok] / case.std[ok]))
    assert ratio < 1e-6, f"kill after line {k}: parameters differ by {ratio:.3g} std"
    return ratio


def _kill_everywhere(tmp_path, robot, method, request, nominal, points=None) -> tuple[int, float]:
    cfg = _config(tmp_path, robot)
    with SimulatorProcess(robot, truth=_truth(tmp_path, robot), config=str(cfg), seed=21,
                          pose_noise=True) as sim:
        case = _uninterrupted(tmp_path, sim, cfg, method, request, nominal)
        n = len(case.lines)
        kills = points if points is not None else [(k, p) for k in range(n)
                                                   for p in (False, True)]
        worst = 0.0
        for k, partial in kills:
            records, x = _resume_after(tmp_path, case, k % n, partial)
            worst = max(worst, _check_same(case, k % n, records, x))
    return len(kills), worst


def _pm_known() -> dict:
    robot = get_robot("agebot-pm")
    xi = load_truth(FIX / "truth" / "agebot-pm-unseen.json").xi()
    return {k: float(xi[robot.index(k)]) for k in ("q3_off", "k3")}


# lines of an sm-distance-tilt trace: 0 header, 1 info, 2 reference, 3 its event, 4 plan,
# 5... poses; of a pm-fk trace: 0 header, 1 plan (scout), 2... poses, then the main plan
SM_POINTS = [(0, True), (1, False), (2, True), (3, False), (4, False), (4, True), (5, False),
             (9, True), (-5, False)]
PM_POINTS = [(0, True), (1, False), (1, True), (3, False), (14, False), (15, True), (-3, False)]


@pytest.mark.heavy
def test_kill_at_key_lines_sm_distance_tilt(tmp_path, no_report):
    """Between the reference and the plan (the case that once gave L2 = -1.25 m),
    mid-line, mid-poses and after the last pose."""
    n, worst = _kill_everywhere(tmp_path, "agebot-sm", "sm-distance-tilt",
                                PlanRequest(count=10, validation=2, seed=3), {}, SM_POINTS)
    assert n == len(SM_POINTS) and worst < 1e-6


@pytest.mark.heavy
def test_kill_at_key_lines_pm_fk(tmp_path, no_report):
    n, worst = _kill_everywhere(tmp_path, "agebot-pm", "pm-fk",
                                PlanRequest(count=14, validation=2, seed=2), _pm_known(),
                                PM_POINTS)
    assert n == len(PM_POINTS) and worst < 1e-6


@pytest.mark.slow
@pytest.mark.parametrize("robot, method, request_, nominal", [
    ("agebot-sm", "sm-distance-tilt", PlanRequest(count=10, validation=2, seed=3), {}),
    ("agebot-pm", "pm-fk", PlanRequest(count=14, validation=2, seed=2), None),
])
def test_kill_after_every_line_and_mid_line(tmp_path, robot, method, request_, nominal,
                                           no_report):
    n, worst = _kill_everywhere(tmp_path, robot, method, request_,
                                _pm_known() if nominal is None else nominal)
    print(f"{method}: {n} kill points, largest parameter difference {worst:.3g} std")
    assert n >= 40 and worst < 1e-6


def test_poses_skipped_for_a_fault_are_measured_again_on_resume(tmp_path):
    """Offline (no devices): a plan with one pose skipped for a fault and one for lack
    of contact; the resumed session measures the first again, not the second, and
    says what it will redo."""
    from station.recording import resume

    config, out = referenced_folder(tmp_path)
    with Session(config, "sm-distance-tilt", out, request=PlanRequest(count=6, validation=2)) as s:
        plan = s.plan()
        s._skip(plan[1], "pose 1 skipped", resume.FAULT)
        s._skip(plan[2], "pose 2 skipped: no contact", resume.NO_CONTACT)
        assert [p.index for p in s.pending] == [0, 3, 4, 5, 6, 7]
    with Session(config, "sm-distance-tilt", out) as again:
        todo = again.redo()
        assert [p.index for p in again.pending] == [0, 1, 3, 4, 5, 6, 7]
        assert todo.remeasure == (1,) and todo.rezero and not todo.plan
        assert "measure the skipped poses 1 again" in todo.describe()
        assert any("measure the skipped poses 1 again" in e["message"]
                   for e in again.events if e["kind"] == "resume")
