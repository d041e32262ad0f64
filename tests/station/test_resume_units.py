"""The session's resume decisions (station.resume) on synthetic trace events and
session states: which skipped poses are measured again, why a pose was skipped,
what must come before the next measurement, and a trace cut in its header. Each
test takes milliseconds (the whole-session resume tests are
tests/station/test_resume.py); bench/mutation.py session-resume runs these.
"""
from types import SimpleNamespace

import numpy as np
import pytest

from station import resume
from station.resume import DROPPED, FAULT, NO_CONTACT, Redo, redo, remeasurable, skip_reason


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
