"""What a session must redo before it measures again: the one place that decides.

A session's only state is its trace (:mod:`station.recording.trace`); a process that starts on
an existing trace knows nothing of the devices' state the previous one left. From
what the trace holds and what this process did already, :func:`redo` says which of
these steps must come before the next measurement:

``capture_reference``  the method needs a reference and the trace has none (the
                       previous process died before the reference record);
``rezero``             a distance method whose reference is recorded but whose
                       draw-wire was not checked by this process: drive back to the
                       reference (the cable is attached there), keep a zero that still
                       reads the reference's tare, zero again one that was lost (a
                       power-cycled sensor; :meth:`Session.rezero_at_reference`).
                       Needed whatever else is left (no plan yet, poses pending,
                       skipped poses to measure again);
``plan``               no plan is recorded (the process died between the reference
                       and the plan, or before either);
``remeasure``          poses skipped because of a device fault: measured again once
                       the fault is cleared (poses skipped for lack of contact in
                       guided touching stay skipped, with their pair partners).

Which poses are done and which remain comes from the trace too: :func:`restore`
replays its plan events (:func:`recorded_plan`), its pose records and its skips
into a :class:`Restored` state, :func:`pending` lists what remains to measure, and
:func:`finished` tells a session measured and exported (left as it is) from one
to go on with.

:meth:`station.session.session.Session.run` (headless) and the GUI's controller both ask
:meth:`Session.redo <station.session.session.Session.redo>`; :meth:`Session.execute`
re-zeroes itself when :func:`redo` says so, so no caller can measure distances
against a lost zero.
"""
from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path

from station.recording.planned_pose import PlannedPose

# why a pose was skipped (the ``reason`` of a ``skip`` event); DROPPED: a wrist round
# dropped and re-planned because the model missed the measured orientation (final)
FAULT, NO_CONTACT, DROPPED = "fault", "no contact", "dropped"


@dataclass(frozen=True)
class Redo:
    """The steps a session must take before measuring (module docstring)."""

    capture_reference: bool
    rezero: bool
    plan: bool
    remeasure: tuple[int, ...] = ()

    @property
    def nothing(self) -> bool:
        return not (self.capture_reference or self.rezero or self.plan or self.remeasure)

    def describe(self) -> str:
        """The steps in words, for the ``resume`` event and the operator."""
        steps = []
        if self.capture_reference:
            steps.append("capture the reference")
        if self.rezero:
            steps.append("return to the reference and zero the draw-wire again")
        if self.plan:
            steps.append("plan the poses")
        if self.remeasure:
            steps.append(f"measure the skipped poses {', '.join(map(str, self.remeasure))} "
                         "again")
        return "; ".join(steps) if steps else "nothing to redo"


def skip_reason(event: dict) -> str:
    """Why a ``skip`` event skipped its pose (traces before ``reason``: from the text)."""
    reason = event.get("reason")
    if reason in (FAULT, NO_CONTACT, DROPPED):
        return reason
    return NO_CONTACT if NO_CONTACT in str(event.get("message", "")) else FAULT


def remeasurable(events: list[dict], measured) -> set[int]:
    """Plan indices skipped for a device fault and not measured since."""
    reasons: dict[int, str] = {}
    for ev in events:
        if ev.get("kind") == "skip" and "plan_index" in ev:
            i = int(ev["plan_index"])
            if reasons.get(i) not in (NO_CONTACT, DROPPED):   # a lack of contact is final
                reasons[i] = skip_reason(ev)
    return {i for i, r in reasons.items() if r == FAULT and i not in measured}


def redo(session) -> Redo:
    """What ``session`` (a :class:`station.session.session.Session`) must do before measuring."""
    needs_ref = session.needs_reference and session.reference_qm is None
    work_left = not session.plan_poses or bool(session.pending) or bool(session.remeasure)
    rezero = (not needs_ref and session.reference_qm is not None and work_left
              and "distance" in session.info.channels and not session.zeroed)
    return Redo(capture_reference=needs_ref, rezero=rezero, plan=not session.plan_poses,
                remeasure=tuple(sorted(session.remeasure)))


def unstarted(trace_path: Path) -> bool:
    """True (and the file removed) when a trace holds no complete line: the previous
    process died while writing its header, so nothing was recorded and the session
    starts anew; False when there is no such file or it has a header to resume."""
    try:
        raw = trace_path.read_bytes()
    except FileNotFoundError:
        return False
    if b"\n" in raw:
        return False
    os.unlink(trace_path)
    return True


def written_by_a_command(trace_path: Path) -> str | None:
    """The command that wrote a trace whose header says it was not recorded by a session
    (``station.generator``: ``app.py trace generate``; ``station.imported_from``: ``app.py
    trace import``), else None (its first line only is read)."""
    with open(trace_path, "rb") as f:
        first = f.readline()
    try:
        station = json.loads(first).get("station") or {}
    except (ValueError, AttributeError):
        return None               # the trace reader names what is wrong with it
    if not isinstance(station, dict):
        return None
    return ("app.py trace generate" if "generator" in station else
            "app.py trace import" if "imported_from" in station else None)


def recorded_plan(trace) -> tuple[list[PlannedPose], set[int], dict[int, dict]]:
    """What a trace says of its session's plan: the planned poses (``plan`` events, a
    replacing one dropping those before it), the skipped plan indices and the measured
    pose records by plan index."""
    plan: list[PlannedPose] = []
    skipped: set[int] = set()
    for ev in trace.events:
        if ev.get("kind") == "plan":
            poses = [PlannedPose.from_record(r) for r in ev.get("poses", ())]
            plan = poses if ev.get("replace", True) else plan + poses
        elif ev.get("kind") == "skip" and "plan_index" in ev:
            skipped.add(int(ev["plan_index"]))
    measured = {int(p["plan_index"]): p for p in trace.poses if "plan_index" in p}
    return plan, skipped, measured


@dataclass(frozen=True)
class Restored:
    """A resumed session's poses, from its trace (:func:`restore`)."""

    plan: list           # the planned poses (PlannedPose), in plan order
    measured: dict       # plan index -> pose record
    skipped: set         # plan indices skipped for good (no contact, dropped)
    remeasure: set       # plan indices skipped for a fault: measured again
    next_index: int      # the next pose record's index


def restore(trace) -> Restored:
    """Which poses of ``trace``'s session are done, skipped for good or to be measured
    again, and the index its next pose record takes."""
    plan, skipped, measured = recorded_plan(trace)
    again = remeasurable(trace.events, measured)
    nxt = (int(trace.poses[-1]["index"]) + 1) if trace.poses else 0
    return Restored(plan, measured, skipped - again, again, nxt)


def pending(plan, measured, skipped, held=()) -> list:
    """The planned poses still to measure: neither recorded, nor skipped, nor touched
    and held for their pair (in plan order)."""
    return [p for p in plan if p.index not in measured and p.index not in skipped
            and p.index not in held]


def reported_since_last_pose(trace_path: Path) -> bool:
    """The trace ends with its report written: a ``report`` event after its last pose,
    skip or plan record (a line that is not JSON, a crash's half line, is passed over)."""
    last_pose = last_report = -1
    with open(trace_path, encoding="utf-8") as f:
        for n, line in enumerate(f):
            try:
                rec = json.loads(line)
            except ValueError:
                continue
            if rec.get("record") == "pose" or rec.get("kind") in ("skip", "plan"):
                last_pose = n
            elif rec.get("kind") == "report":
                last_report = n
    return last_report > last_pose


def finished(trace_path: Path, pending_poses, outputs) -> bool:
    """A session measured and exported: nothing pending, its report recorded after its
    last pose and every file of ``outputs`` (parameter file, report) written."""
    return (not pending_poses and reported_since_last_pose(trace_path)
            and all(Path(f).is_file() for f in outputs))
