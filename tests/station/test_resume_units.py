"""The session's resume decisions (station.recording.resume) on synthetic trace events and
session states: which skipped poses are measured again, why a pose was skipped,
what must come before the next measurement, a trace cut in its header, and which
poses a resumed session counts as done, skipped or still to measure. Each
test takes milliseconds (the whole-session resume tests are
tests/station/test_resume.py); bench/mutation.py session-resume runs these.
"""
import json
from types import SimpleNamespace

import numpy as np
import pytest

from station.recording import resume
from station.recording.planned_pose import PlannedPose
from station.recording.resume import DROPPED, FAULT, NO_CONTACT, Redo, redo, remeasurable, skip_reason


def _skip(i, reason=None, message="pose skipped"):
    ev = {"kind": "skip", "plan_index": i, "message": message}
    if reason is not None:
        ev["reason"] = reason
    return ev


# -- why a pose was skipped ------------------------------------------------------------
@pytest.mark.parametrize("reason", [FAULT, NO_CONTACT, DROPPED])
def test_skip_reason_is_the_recorded_one(reason):
    assert skip_reason({"kind": "skip", "reason": reason, "message": "no contact"
                        if reason == FAULT else "x"}) == reason


def test_skip_reason_of_older_traces_comes_from_the_text():
    assert skip_reason({"kind": "skip", "message": "pose 3: no contact after 4 tries"}) == NO_CONTACT
    assert skip_reason({"kind": "skip", "message": "pose 3 skipped: EMCY 0x8612"}) == FAULT
    assert skip_reason({"kind": "skip"}) == FAULT
    assert skip_reason({"kind": "skip", "message": None}) == FAULT
    # an unknown reason is not trusted: the text decides
    assert skip_reason({"kind": "skip", "reason": "other", "message": "no contact"}) == NO_CONTACT
    assert skip_reason({"kind": "skip", "reason": "other", "message": "timeout"}) == FAULT


def test_the_reasons_are_the_trace_s_words():
    """Written into traces: changing them would misread every existing trace."""
    assert (FAULT, NO_CONTACT, DROPPED) == ("fault", "no contact", "dropped")


# -- which skipped poses are measured again ------------------------------------------------
def test_faults_not_measured_since_are_remeasured():
    events = [{"kind": "plan", "plan_index": 0}, _skip(2, FAULT), _skip(5, FAULT),
              _skip(7, NO_CONTACT), _skip(8, DROPPED), {"kind": "pose", "message": "x"}]
    assert remeasurable(events, measured={5}) == {2}
    assert remeasurable(events, measured=set()) == {2, 5}
    assert remeasurable(events, measured={2, 5, 7, 8}) == set()
    assert remeasurable([], set()) == set()


def test_plan_index_is_read_as_an_integer():
    assert remeasurable([_skip("4", FAULT)], measured=set()) == {4}
    assert remeasurable([_skip("4", FAULT)], measured={4}) == set()
    assert remeasurable([_skip(4.0, FAULT)], measured=set()) == {4}


def test_only_skip_events_with_a_plan_index_count():
    events = [{"kind": "skip", "reason": FAULT, "message": "no index"},
              {"kind": "fault", "plan_index": 3, "reason": FAULT},
              {"plan_index": 6, "reason": FAULT}]
    assert remeasurable(events, set()) == set()


def test_lack_of_contact_and_dropped_are_final():
    """A later fault does not revive a pose skipped for lack of contact or dropped."""
    for final in (NO_CONTACT, DROPPED):
        assert remeasurable([_skip(3, final), _skip(3, FAULT)], set()) == set()
    # the other way round: the later final reason wins over the fault
    for final in (NO_CONTACT, DROPPED):
        assert remeasurable([_skip(3, FAULT), _skip(3, final)], set()) == set()
    assert remeasurable([_skip(3, FAULT), _skip(3, FAULT)], set()) == {3}


def test_old_traces_reason_from_text():
    events = [_skip(1, message="pose 1: no contact"), _skip(2, message="pose 2 skipped"),
              _skip(1, message="pose 1 skipped")]
    assert remeasurable(events, set()) == {2}


# -- what must come before the next measurement -------------------------------------------
def _session(**kw):
    base = dict(needs_reference=True, reference_qm=np.zeros(4), plan_poses=[object()],
                pending=[], remeasure=set(), info=SimpleNamespace(channels=("qm", "distance")),
                zeroed=True)
    base.update(kw)
    return SimpleNamespace(**base)


def test_nothing_to_redo():
    r = redo(_session())
    assert r == Redo(False, False, False, ()) and r.nothing
    assert r.describe() == "nothing to redo"


def test_reference_missing():
    r = redo(_session(reference_qm=None, plan_poses=[], zeroed=False))
    assert r.capture_reference and r.plan and not r.rezero and not r.nothing
    assert r.describe() == "capture the reference; plan the poses"
    # a method without a reference needs none
    r = redo(_session(needs_reference=False, reference_qm=None, zeroed=False, plan_poses=[]))
    assert not r.capture_reference and not r.rezero and r.plan
    assert r.describe() == "plan the poses"


@pytest.mark.parametrize("work", ["no plan", "pending", "remeasure"])
def test_rezero_when_distances_are_left_and_this_process_did_not_zero(work):
    left = {"no plan": dict(plan_poses=[]), "pending": dict(pending=[object()]),
            "remeasure": dict(remeasure={4, 1})}[work]
    r = redo(_session(zeroed=False, **left))
    assert r.rezero and not r.capture_reference and not r.nothing
    assert r.plan is (work == "no plan")
    assert r.remeasure == ((1, 4) if work == "remeasure" else ())
    assert redo(_session(zeroed=True, **left)).rezero is False
    # no distance channel: no draw-wire to zero
    nodist = redo(_session(zeroed=False, info=SimpleNamespace(channels=("qm", "tilt")), **left))
    assert not nodist.rezero
    # no reference recorded (a method without one): nothing to return to
    noref = redo(_session(zeroed=False, needs_reference=False, reference_qm=None, **left))
    assert not noref.rezero


def test_no_rezero_when_no_work_is_left():
    assert not redo(_session(zeroed=False)).rezero
    assert redo(_session(zeroed=False)).nothing


def test_remeasure_is_sorted_and_described():
    r = redo(_session(remeasure={9, 2, 5}))
    assert r.remeasure == (2, 5, 9) and not r.nothing and not r.rezero
    assert r.describe() == "measure the skipped poses 2, 5, 9 again"


def test_describe_lists_every_step_in_order():
    r = Redo(capture_reference=True, rezero=True, plan=True, remeasure=(3, 1))
    assert r.describe() == ("capture the reference; return to the reference and zero the "
                            "draw-wire again; plan the poses; measure the skipped poses 3, 1 "
                            "again")
    assert Redo(False, True, False).describe() == ("return to the reference and zero the "
                                                   "draw-wire again")
    for kw in (dict(capture_reference=True), dict(rezero=True), dict(plan=True),
               dict(remeasure=(0,))):
        assert not Redo(**{**dict(capture_reference=False, rezero=False, plan=False), **kw}).nothing
    assert Redo(False, False, False).remeasure == ()


# -- a trace cut in its header ----------------------------------------------------------
def test_unstarted_trace(tmp_path):
    path = tmp_path / "trace.jsonl"
    assert resume.unstarted(path) is False  # no file: nothing to resume, nothing removed
    path.write_bytes(b'{"record": "header", "robot": "agebot')
    assert resume.unstarted(path) is True and not path.exists()
    path.write_bytes(b"")
    assert resume.unstarted(path) is True and not path.exists()
    path.write_bytes(b'{"record": "header"}\n{"record": "po')
    assert resume.unstarted(path) is False and path.exists()
    path.write_bytes(b'{"record": "header"}\n')
    assert resume.unstarted(path) is False and path.read_bytes() == b'{"record": "header"}\n'


# -- which poses are done and which remain (the trace replayed) ----------------------------
def _plan(indices, replace=None, **kw):
    ev = {"kind": "plan", "poses": [{"index": i, "qm": [0.1 * i, 0.0], "target": [float(i)],
                                     **kw} for i in indices]}
    if replace is not None:
        ev["replace"] = replace
    return ev


def _pose(index, plan_index=None):
    rec = {"record": "pose", "index": index, "qm": [0.0]}
    if plan_index is not None:
        rec["plan_index"] = plan_index
    return rec


def _trace(events=(), poses=()):
    return SimpleNamespace(events=list(events), poses=list(poses))


def test_recorded_plan_replays_plan_events():
    tr = _trace([_plan([0, 1, 2], use="validation", round=2, group=7), _skip(1, FAULT),
                 {"kind": "info", "plan_index": 0}, {"kind": "skip", "message": "no index"}],
                [_pose(0, 0), _pose(1), _pose(2, "2")])
    plan, skipped, measured = resume.recorded_plan(tr)
    assert [p.index for p in plan] == [0, 1, 2]
    assert plan[0] == PlannedPose(0, (0.0, 0.0), (0.0,), "validation", 2, 7)
    assert skipped == {1}
    assert measured == {0: tr.poses[0], 2: tr.poses[2]} and list(measured) == [0, 2]
    assert resume.recorded_plan(_trace()) == ([], set(), {})


def test_a_replacing_plan_drops_the_poses_before_it_and_a_round_adds():
    first, second = _plan([0, 1, 2]), _plan([5, 6])
    assert [p.index for p in resume.recorded_plan(_trace([first, second]))[0]] == [5, 6]
    assert [p.index for p in resume.recorded_plan(
        _trace([first, _plan([5, 6], replace=True)]))[0]] == [5, 6]
    added = resume.recorded_plan(_trace([first, _plan([3, 4], replace=False)]))[0]
    assert [p.index for p in added] == [0, 1, 2, 3, 4]
    # a plan event without poses empties the plan; a round without poses adds none
    assert resume.recorded_plan(_trace([first, {"kind": "plan"}]))[0] == []
    assert len(resume.recorded_plan(_trace([first, {"kind": "plan", "replace": False}]))[0]) == 3
    # defaults of a pose record: a fit pose of round 0 in no pair
    p = resume.recorded_plan(_trace([first]))[0][1]
    assert (p.use, p.round, p.group) == ("fit", 0, None)


def test_restore_splits_skips_into_final_and_to_measure_again():
    tr = _trace([_plan(range(8)), _skip(1, FAULT), _skip(2, NO_CONTACT), _skip(3, FAULT),
                 _skip(4, DROPPED)], [_pose(0, 0), _pose(1, 3), _pose(2, 5)])
    r = resume.restore(tr)
    assert [p.index for p in r.plan] == list(range(8))
    assert set(r.measured) == {0, 3, 5}
    assert r.skipped == {2, 3, 4}          # 3 was skipped, then measured: a skip of record
    assert r.remeasure == {1}              # a fault, not measured since
    assert r.next_index == 3               # after the last pose record's index
    assert resume.pending(r.plan, r.measured, r.skipped | r.remeasure) == [
        p for p in r.plan if p.index in (6, 7)]
    assert [p.index for p in resume.pending(r.plan, r.measured, r.skipped)] == [1, 6, 7]


def test_restore_next_index_follows_the_last_record_not_the_count():
    tr = _trace([_plan([0, 1])], [_pose(4, 0), _pose("9", 1)])
    assert resume.restore(tr).next_index == 10
    assert resume.restore(_trace([_plan([0, 1])])).next_index == 0
    empty = resume.restore(_trace())
    assert (empty.plan, empty.measured, empty.skipped, empty.remeasure) == ([], {}, set(), set())


def test_pending_keeps_plan_order_and_leaves_out_done_skipped_and_held():
    plan = [PlannedPose(i, (0.0,), (0.0,)) for i in (4, 0, 3, 1, 2)]
    assert resume.pending(plan, {}, set()) == plan
    assert [p.index for p in resume.pending(plan, {3: {}}, {1}, {2: {}})] == [4, 0]
    assert [p.index for p in resume.pending(plan, {4: {}}, set(), ())] == [0, 3, 1, 2]
    assert resume.pending(plan, {i: {} for i in range(5)}, set()) == []
    assert resume.pending([], {}, set()) == []


def _lines(path, *recs, tail=b""):
    path.write_bytes(b"".join(json.dumps(r).encode() + b"\n" for r in recs) + tail)
    return path


def test_reported_since_last_pose(tmp_path):
    hdr, pose, report = {"record": "header"}, _pose(0, 0), {"record": "event", "kind": "report"}
    skip, plan = {"record": "event", **_skip(1, FAULT)}, {"record": "event", **_plan([0])}
    p = tmp_path / "trace.jsonl"
    assert resume.reported_since_last_pose(_lines(p, hdr, pose, report))
    assert not resume.reported_since_last_pose(_lines(p, hdr, report, pose))
    assert not resume.reported_since_last_pose(_lines(p, hdr, pose))
    assert not resume.reported_since_last_pose(_lines(p, hdr))
    for last in (skip, plan):    # a skip or a new plan after the report: not finished
        assert not resume.reported_since_last_pose(_lines(p, hdr, pose, report, last))
        assert resume.reported_since_last_pose(_lines(p, hdr, pose, last, report))
    # other events after the report (an export, a resume) leave it finished
    assert resume.reported_since_last_pose(
        _lines(p, hdr, pose, report, {"record": "event", "kind": "export"}))
    # a crash's half line is passed over, whichever record it was
    assert resume.reported_since_last_pose(_lines(p, hdr, pose, report, tail=b'{"record": "po'))
    assert not resume.reported_since_last_pose(_lines(p, hdr, pose, tail=b'{"kind": "rep'))
    # and so is a line that is not JSON before later records (they still count)
    assert resume.reported_since_last_pose(_lines(p, hdr, pose, tail=b'garbled\n' + json.dumps(
        report).encode() + b"\n"))
    # a report with nothing measured yet (the header is line 0, the report line 1)
    assert resume.reported_since_last_pose(_lines(p, hdr, report))


def test_finished_needs_nothing_pending_the_report_recorded_and_every_output(tmp_path):
    p = _lines(tmp_path / "trace.jsonl", {"record": "header"}, _pose(0, 0),
               {"record": "event", "kind": "report"})
    out = [tmp_path / "params.json", tmp_path / "report.html"]
    for f in out:
        f.write_text("x")
    assert resume.finished(p, [], out)
    assert not resume.finished(p, [PlannedPose(1, (0.0,), (0.0,))], out)
    out[1].unlink()
    assert not resume.finished(p, [], out)
    out[1].mkdir()                  # a folder of that name is not the file
    assert not resume.finished(p, [], out)
    out[1].rmdir()
    out[1].write_text("x")
    _lines(p, {"record": "header"}, {"record": "event", "kind": "report"}, _pose(0, 0))
    assert not resume.finished(p, [], out)
