"""What a session must redo before it measures again: the one place that decides.

A session's only state is its trace (:mod:`station.trace`); a process that starts on
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

:meth:`station.session.Session.run` (headless) and the GUI's controller both ask
:meth:`Session.redo <station.session.Session.redo>`; :meth:`Session.execute`
re-zeroes itself when :func:`redo` says so, so no caller can measure distances
against a lost zero.
"""
from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

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
    """What ``session`` (a :class:`station.session.Session`) must do before measuring."""
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
