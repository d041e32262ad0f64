"""The session's reference step: where the method's distances are measured from.

The operator (or the headless run) brings the end effector to the suggested point
(:meth:`ReferenceStep.reference_target`: the robot kind's, :mod:`station.session.robot_kinds`),
attaches the draw-wire there and captures: the draw-wire is zeroed, the station's
devices are checked by a test move (:mod:`station.session.plausibility`) and the pose is
measured as any other and written as the trace's reference record. After a restart the
session drives back there and checks that the draw-wire kept its zero
(:meth:`ReferenceStep.rezero_at_reference`); :meth:`ReferenceStep.redo` says what a
resumed session must do first (:func:`station.recording.resume.redo`).
"""
from __future__ import annotations

import math

import numpy as np

from calibration.errors import StationError
from station.planning.envelope import limit_violation
from station.recording import resume
from station.recording.trace import utc_now
from station.session import plausibility


class ReferenceStep:
    """The reference step of a :class:`~station.session.session.Session` (a part of it:
    reads ``info``, ``robot``, ``nominal``, ``config``, ``measured``, ``kind``; writes
    ``reference_qm``, ``reference_record``, ``zeroed``; retries by
    :meth:`~station.session.retries.Retries._reference_retried`)."""

    @property
    def needs_reference(self) -> bool:
        return self.info.reference is not None

    def reference_target(self):
        """``(qm, role, instructions)`` for the reference step (qm None: no reference)."""
        return self.kind.reference_target()

    def capture_reference(self, qm=None) -> np.ndarray:
        """Record the current pose (``qm`` given: drive there first, the headless run)
        as the reference: zero the draw-wire (the cable is attached here), then measure
        the pose as any other (averaged, checked) and write the reference record. The
        zero is one reading with noise, so the record says ``zero = "reading"`` (the
        method calibrates ``distance_off``) and keeps the averaged reading there as
        ``tare`` (checked again on resume). Before any pose is measured the reference
        may be captured again: the new record (and its zero) replaces the earlier one,
        in the trace as on resume.

        A device fault on the way (the move, the plausibility test move, the zero, a
        reading of the tare) is retried as a pose's is (:meth:`_reference_retried`):
        the arm back where the step started and the whole capture again (zero and
        every reading), so the record never mixes readings from before and after it."""
        if not self.needs_reference:
            raise StationError(f"method {self.method} has no reference step")
        if self.reference_qm is not None and self.measured:
            raise StationError("poses were measured from this reference: a new reference "
                               "needs a new session folder")
        again = self.reference_qm is not None
        rig = self._rig()
        where = None if qm is None else [float(v) for v in qm]
        if where is not None:
            why = limit_violation(where, self.config.envelope)
            if why is not None:
                raise StationError(f"not moved: {why} ([envelope] of the station config)")

        def capture(attempt: int):
            nonlocal where
            if where is None:          # here: where the operator left the arm
                where = [float(v) for v in rig.qm()]
            elif (attempt or qm is not None) and rig.can_move:
                rig.move_to(where)     # there, or back after a fault (a test move's)
            found = plausibility.check_reference(self)   # a mis-configured device stops here
            if rig.drawwire is not None:
                rig.zero_drawwire()
            return found, rig.snapshot(on_retake=self._settling("the reference step"))

        found, snap = self._reference_retried("the reference step", capture)
        qm = np.array([snap.mean[f"qm{i + 1}"] for i in range(self.robot.n_actuators)])
        rec = {"record": "reference", "role": self.info.reference, "qm": qm.tolist(),
               "t": utc_now(), "samples": snap.samples}
        if rig.drawwire is not None:
            rec["zero"] = "reading"
            rec["tare"] = _tare(snap)
        if "tilt" in snap.mean:
            rec["tilt"] = float(snap.mean["tilt"])
        w = self._ensure_trace()
        w.append(rec)
        self.reference_qm = qm
        self.reference_record = rec
        self.zeroed = rig.drawwire is not None
        if found:
            self._event("info", found)
        how = "captured again" if again else "captured"
        self._event("reference", f"{self.info.reference} {how} at qm {np.round(qm, 4).tolist()}"
                    + (" (the draw-wire zeroed there; it replaces the earlier reference)"
                       if again else ""))
        return qm

    def reference_offset(self, qm=None) -> float | None:
        """Distance (m, nominal model) from the reference ``qm`` (default: the captured
        one) to the suggested point; None without a reference step."""
        target, _, _ = self.reference_target()
        qm = self.reference_qm if qm is None else qm
        if target is None or qm is None:
            return None
        a = self.robot.fk(np.asarray(qm, dtype=float), self.nominal)[0, :3]
        b = self.robot.fk(np.asarray(target, dtype=float), self.nominal)[0, :3]
        return float(np.linalg.norm(a - b))

    def rezero_at_reference(self) -> None:
        """After a restart: drive back to the recorded reference and check the
        draw-wire there. One that kept its zero reads the reference's ``tare`` again
        (within 4 standard errors and two counts) and is left alone: every pose keeps
        the one ``distance_off``. One that lost it (power-cycled) is zeroed again; that
        new zero is another noisy reading, said in an event (docs/methods.md)."""
        if self.reference_qm is None or self._rig().drawwire is None:
            return
        tare = (self.reference_record or {}).get("tare")
        target = [float(v) for v in self.reference_qm]

        def check(attempt: int):
            """Back at the reference, read the draw-wire; zero it where it lost its zero.
            A fault anywhere: all of it again (the zero where it is read anew)."""
            self.move_to(target)
            now = _tare(self.rig.snapshot(
                on_retake=self._settling("the return to the reference")))
            if tare is not None:
                se = math.hypot(tare["std"] / math.sqrt(max(tare["samples"], 1)),
                                now["std"] / math.sqrt(max(now["samples"], 1)))
                tol = 4 * se + 2 * self.config.drawwire.metres_per_count
                if abs(now["distance"] - tare["distance"]) <= tol:
                    return now, True
            self.rig.zero_drawwire()
            return now, False

        now, kept = self._reference_retried("the return to the reference", check)
        if kept:
            self._event("reference", f"back at the reference: draw-wire reads "
                        f"{now['distance']:.6g} m (at capture {tare['distance']:.6g} m): "
                        "it kept its zero", tare=now)
            self.zeroed = True
            return
        self._event("warning", f"back at the reference: draw-wire read {now['distance']:.6g} m "
                    f"(at capture {tare['distance'] if tare else float('nan'):.6g} m): it lost "
                    "its zero and was zeroed again; the poses measured from now on carry that "
                    "new zero's reading noise (a common offset of about one reading's std)",
                    tare=now)
        self.zeroed = True

    def redo(self) -> resume.Redo:
        """What must come before the next measurement (:func:`station.recording.resume.redo`):
        capture the reference, return to it and re-zero, plan, measure skipped poses again."""
        return resume.redo(self)


def _tare(snap) -> dict:
    """The draw-wire's averaged reading of a snapshot: ``distance`` (m), ``std`` (m, of
    one reading), ``samples``."""
    return {"distance": float(snap.mean["distance"]), "std": float(snap.std.get("distance", 0.0)),
            "samples": int(snap.samples)}
